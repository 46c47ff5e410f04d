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
    """``testbed view``: the viewer's exit code."""
    return view(args.file, web=args.web, grpc_port=args.grpc_port, web_port=args.web_port)
