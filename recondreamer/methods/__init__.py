"""ReconDreamer's training loop (PDUS with online DriveRestorer restoration) and the DriveDreamer4D baseline.

``pdus`` holds Algorithm 1 as a pure schedule and the 50/50 mixing rule, ``loop`` the trainer
callback and ``train_recondreamer``, ``dd4d`` the generate-once baseline, ``novel`` the on-disk
novel-video folders both write. See ``docs/methods.md``.
"""
