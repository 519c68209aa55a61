"""Session set-up shared by every test module.

OpenMP threads that spin while they wait (libgomp's default) made small torch and splat
operations 20-30x slower on a busy 2-core machine; passive waiting keeps them fast. It must
be set before torch or the splat kernel loads OpenMP, hence here (pytest imports conftest
first)."""

import os

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
