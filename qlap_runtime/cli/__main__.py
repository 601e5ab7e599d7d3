"""``python -m qlap_runtime.cli``: the ``qlap`` command."""

import sys

from . import main

if __name__ == "__main__":
    sys.exit(main())
