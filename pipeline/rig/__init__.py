"""Per-rig motion models trained from one clip (GANimator, Li et al. 2022).

Training (``train``, ``networks``, ``export``) needs torch; inference (``infer``) needs only
onnxruntime and numpy, so filling a shot never imports torch.
"""
