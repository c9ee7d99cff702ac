"""NeRF from captures on a CPU: encodings, models (vanilla + fast TensoRF-VM default + ablations),
data loading from capture / poses folders, training on a wall-clock budget, the PSNR-vs-time study."""
