"""``testbed run --spawn/--connect/--serve``: the run streamed to a Rerun viewer."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from testbed.experiment.scenario import Scenario
from testbed.rigs import resolve_rig


def check_live_options(args: argparse.Namespace) -> None:
    """``--bind`` (an IP address, with --spawn/--serve only; a warning when other machines
    can reach it) and the live options that do not go with --realtime."""
    if args.realtime and (args.spawn or args.connect or args.serve):
        raise ValueError("--spawn/--connect/--serve are not available with --realtime")
    if args.bind is None:
        return
    if not (args.spawn or args.serve):
        raise ValueError("--bind applies to --spawn and --serve (what listens)")
    from testbed.outputs.live import check_bind

    address, loopback = check_bind(args.bind)
    if not loopback:
        print(f"testbed: warning: --bind {address}: the viewer is reachable from other "
              "machines (anyone who can reach this one can watch the run)", file=sys.stderr,
              flush=True)


def open_live(args: argparse.Namespace, scenario: Scenario) -> Any:
    """The live view asked for by --spawn / --connect / --serve, or None."""
    if not (args.spawn or args.connect or args.serve):
        return None
    from testbed.outputs.live import DEFAULT_BIND, LiveView, open_recording

    bind = DEFAULT_BIND if args.bind is None else args.bind
    rec, url = open_recording(f"testbed/{resolve_rig(scenario.rig).name}", spawn=args.spawn,
                              connect=args.connect, serve=args.serve,
                              grpc_port=args.grpc_port, web_port=args.web_port, bind=bind)
    if url is not None:
        print(f"Rerun web viewer: open {url}", flush=True)
    return LiveView(rec)


def finish_live(args: argparse.Namespace, live: Any) -> None:
    """Keep a --serve server up until Ctrl-C; disconnect the others."""
    from testbed.outputs.live import stop

    try:
        if args.serve:
            print("serving the run; press Ctrl-C to stop", flush=True)
            while True:
                time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        stop(live.rec)
