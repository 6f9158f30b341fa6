"""The generative stack: latent autoencoder, world models (sd / svd / dd2), DriveRestorer and the
DriveDreamer4D generator (see ``docs/generative.md``).

Modules: ``config`` (dataclass configs), ``autoencoder``, ``unet``, ``diffusion`` (schedule, DDIM),
``masks`` (dd2_mask training masks), ``data`` (corpus and pairs as latents), ``pairs``
(``make-pairs``), ``training``, ``models`` (checkpoints -> models), ``inference``
(``restore_clip``, ``generate_clip``), ``scoring`` (a restored clip against its truth), ``checkpoint``,
``commands`` (CLI). Clips on disk: ``recondreamer.frames_io``.
Nothing is imported here, so ``recondreamer --help`` does not load torch.
"""
