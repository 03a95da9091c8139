"""``python -m vehicle_common.bag_recovery BAG``: the former path of ``bag_recover``, kept for
console scripts installed before bag I/O moved to :mod:`vehicle_common.bags` (the code is in
:mod:`vehicle_common.bags.recovery`)."""

import sys

from vehicle_common.bags.recovery import main

if __name__ == "__main__":
    sys.exit(main())
