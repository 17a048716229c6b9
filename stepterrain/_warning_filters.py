"""The one lock of the library's ``warnings.catch_warnings`` blocks.

Python's warning filters (``warnings.filters``) and display (``warnings.showwarning``) are the process's, and
``warnings.catch_warnings`` swaps them on entry and puts back what it found on exit: two blocks in two threads that
enter and leave in the order first in, second in, first out, second out leave the first block's filters in the process
for good (its "ignore": every later warning of the process lost), or its recorder (every later warning going into a
list nobody reads). Every such block of the library holds :data:`FILTERS`, so that they run one at a time (the
command line's aside: its ``main()`` runs one command at a time in a process, and a block spanning the whole run
must not hold it, or dask's threaded workers would wait on it for ever); blocks in one thread nest (a batch item's
recording around the raster open of its read), hence a re-entrant lock.
"""

from __future__ import annotations

import threading

#: Held around every ``warnings.catch_warnings`` block of the library (see the module's docstring).
FILTERS = threading.RLock()
