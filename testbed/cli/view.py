"""``testbed view``: open a ``.rrd`` recording in Rerun's viewer (native or web)."""

from __future__ import annotations

import argparse

from testbed.outputs.view import BIND, GRPC_PORT, WEB_PORT, view


def add_arguments(v: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``v``."""
    v.add_argument("file", help="a .rrd file written by testbed (--rrd, reproduce, score)")
    v.add_argument("--web", action="store_true",
                   help=f"host the web viewer on {BIND} and print its URL (headless machines)")
    v.add_argument("--web-port", type=int, default=WEB_PORT)
    v.add_argument("--grpc-port", type=int, default=GRPC_PORT)


def command(args: argparse.Namespace) -> int:
    """``testbed view``: the viewer's exit code.

    On Ctrl-C or SIGTERM the viewer's processes are stopped (:func:`testbed.outputs.view.
    view`) and the command returns: it wrote nothing, so the command line reports
    ``testbed: stopped (SIGINT)`` (or ``SIGTERM``) with the signal's exit code, not that
    partial outputs were removed.
    """
    from testbed.cli.entry import _SIGNALLED, _Terminated

    try:
        return view(args.file, web=args.web, grpc_port=args.grpc_port, web_port=args.web_port)
    except (KeyboardInterrupt, _Terminated):
        if not _SIGNALLED:  # not the command line's own signal handling: as it was
            raise
        return 0  # the entry sees the signal (_SIGNALLED) and exits with its code
