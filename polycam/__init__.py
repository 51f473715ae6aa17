"""polycam core: types, formats and the plenoptic motion solver.

See docs/conventions.md for frames, units and axis orders.
"""

import logging

logging.getLogger(__name__).addHandler(logging.NullHandler())

__version__ = "0.1.0"
