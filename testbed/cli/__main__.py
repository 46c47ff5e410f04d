"""``python -m testbed.cli``: the ``testbed`` command."""

import sys

from testbed.cli.entry import main

if __name__ == "__main__":
    sys.exit(main())
