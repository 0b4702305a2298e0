"""numba kernels of MERSYN: location models, prediction/correction, boundary, resampling,
synthesis rules. Arrays in, arrays out; no file or GUI knowledge."""
