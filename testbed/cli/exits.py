"""The ``testbed`` command's exit codes (the table in :mod:`testbed.cli`)."""

EXIT_FAILURE, EXIT_USAGE, EXIT_FILTER, EXIT_DIVERGED, EXIT_OUTPUT = 1, 2, 3, 4, 5
EXIT_SIGINT, EXIT_SIGTERM = 130, 143
#: The reader of stdout went away (as a shell reports SIGPIPE: 128 + 13).
EXIT_PIPE = 141
