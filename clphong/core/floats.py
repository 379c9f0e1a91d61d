"""float32 constants shared by the host, the float64 reference and the error model.

Each is defined once here; the kernels' own (``FLT_MIN``, ``FLT_MAX``) are
OpenCL's, with the same values.
"""

from __future__ import annotations

import numpy as np

#: float32 unit roundoff, 2^-24 (half an ulp of 1).
U = 2.0 ** -24
#: float64 unit roundoff, 2^-53.
U_D = 2.0 ** -53
#: Smallest normal float32 (OpenCL's FLT_MIN): below it, the kernels' results are
#: subnormal or flushed to zero (``-cl-denorms-are-zero``).
FLT_MIN = float(np.finfo(np.float32).tiny)
#: Largest finite float32 (OpenCL's FLT_MAX).
FLT_MAX = float(np.finfo(np.float32).max)
#: The smallest float64 that rounds to +inf as float32 (FLT_MAX + half an ulp).
F32_ROUNDS_TO_INF = 3.4028235677973366e38
#: Largest finite float16 (OpenEXR HALF).
HALF_MAX = 65504.0
