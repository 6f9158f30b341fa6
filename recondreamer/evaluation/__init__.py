"""Evaluation: NTA-IoU, NTL-IoU, FID, PSNR/SSIM against the true novel views, the models they need
(vehicle detector, lane segmenter, FID features; trained on the synthetic corpus or loaded from local
weights) and the preference study (see ``docs/evaluation.md``)."""
