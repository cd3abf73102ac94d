"""Units of aviation, in SI: the one home of every conversion factor (exact by definition).

Names read as "metres per foot" etc., so ``alt_m = alt_ft * M_PER_FT``.
"""

from __future__ import annotations

#: international foot (1959), exact
M_PER_FT = 0.3048
#: international nautical mile, exact
M_PER_NM = 1852.0
#: one knot, one nautical mile per hour
MPS_PER_KT = M_PER_NM / 3600.0
#: a flight level is 100 ft of pressure altitude
FT_PER_FL = 100.0
M_PER_FL = FT_PER_FL * M_PER_FT
#: one foot per minute (vertical rate)
MPS_PER_FPM = M_PER_FT / 60.0
SECONDS_PER_DAY = 86_400.0
