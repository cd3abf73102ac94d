"""``python -m radar_fusion.tools.bench``: the same as ``radar-fusion bench``."""

from . import main

raise SystemExit(main())
