"""Root conftest: keep Warp's start-up and module-load lines out of test and doctest output."""

import warp as wp

if hasattr(wp.config, "log_level"):
    wp.config.log_level = wp.LOG_ERROR
else:  # pragma: no cover - older Warp
    wp.config.quiet = True
