"""``python -m testbed``: the ``testbed`` command (:func:`testbed.cli.entry.main`)."""

import sys

from testbed.cli import main

if __name__ == "__main__":
    sys.exit(main())
