"""``python -m radar_fusion.tools.simulate``: the same as ``radar-fusion simulate``."""

from . import main

raise SystemExit(main())
