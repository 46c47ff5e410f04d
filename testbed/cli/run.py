"""``testbed run``: one closed-loop episode, its summary table and output files (live
viewing in :mod:`testbed.cli.live`, paced runs in :mod:`testbed.experiment.realtime`)."""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

from testbed.cli import deferred, values
from testbed.cli.live import check_live_options, finish_live, open_live
from testbed.cli.outputs import format_table, say_written, wrote
from testbed.cli.scenario_options import (
    add_scenario_options,
    save_scenario,
    scenario_from_args,
    show_progress,
)
from testbed.experiment.scenario import Scenario
from testbed.io import write_json


def add_arguments(run: argparse.ArgumentParser) -> None:
    """The command's arguments on its subparser ``run``."""
    add_scenario_options(run, 20.0)
    run.add_argument("--rrd", help="write a Rerun recording here")
    run.add_argument("--json", help="write the summary JSON here")
    run.add_argument("--plot", help="write a PNG plot here")
    run.add_argument("--save-log", metavar="FILE", help="write what the sensors gave and the "
                     "inputs applied as a recording (.csv, .npz or .mat: what a real unit's "
                     "log holds, no truth; testbed replay/identify/compare read it)")
    live = run.add_mutually_exclusive_group()
    live.add_argument("--spawn", action="store_true",
                      help="stream the run to a native Rerun viewer started here")
    live.add_argument("--connect", metavar="URL", help="stream the run to a running viewer, "
                      "e.g. rerun+http://127.0.0.1:9876/proxy")
    live.add_argument("--serve", action="store_true", help="serve the run to Rerun's web "
                      "viewer (headless machines): prints the URL, serves until Ctrl-C")
    run.add_argument("--grpc-port", type=values.port, default=9876,
                     help="with --spawn/--serve: the viewer's gRPC port")
    run.add_argument("--web-port", type=values.port, default=9090,
                     help="with --serve: the web port")
    run.add_argument("--bind", metavar="ADDRESS", default=None,
                     help="with --spawn/--serve: the IP address the viewer or server listens "
                     "on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    run.add_argument("--video", help="write an MP4 video of the run here (needs the 'video' "
                     "extra: imageio-ffmpeg)")
    run.add_argument("--realtime", action="store_true", help="pace the run to the wall clock "
                     "(a background thread samples the rig; late commands count as overruns)")
    run.add_argument("--realtime-factor", type=values.positive, default=1.0,
                     help="with --realtime: simulated seconds per wall-clock second")
    deferred.defer_defaults(run)


def command(args: argparse.Namespace) -> int:
    """``testbed run``: one closed-loop episode, summary table and output files."""
    from testbed.experiment import runner

    scenario = scenario_from_args(args)
    check_live_options(args)
    if args.save_scenario:
        return save_scenario(args, scenario)
    if args.realtime:
        return _cmd_run_realtime(args, scenario)
    live = open_live(args, scenario)
    start = time.perf_counter()
    try:
        traj, summary = runner.run(scenario,
                                   record=bool(args.plot or args.rrd or args.video
                                               or args.save_log),
                                   every_step=bool(args.save_log),
                                   progress=None if show_progress(args) else False,
                                   observe=None if live is None else live.attach)
    except BaseException:
        if live is not None:
            from testbed.outputs.live import stop

            stop(live.rec)
        raise
    wall_s = time.perf_counter() - start
    if live is not None:
        from testbed.outputs.viz import run_description

        live.close(run_description(summary["meta"], summary))
    meta = summary.pop("meta")
    result = {"rig": meta["rig"], "filter": meta["scenario"]["estimator"],
              "controller": meta["scenario"]["controller"], "seed": scenario.seed,
              "duration_s": float(scenario.duration_s), **summary, "wall_s": wall_s,
              **scenario_and_meta(meta)}
    print(f"{meta['rig']} | filter {result['filter']} | controller {result['controller']} | "
          f"sensors {meta['sensors']} | {summary['steps']} steps in {wall_s:.2f} s wall")
    print(format_table(summary, summary["units"]))
    if args.json:
        wrote(write_json(args.json, result))
    if args.plot:
        from testbed.outputs.plots import plot_trajectory

        title = (f"{meta['rig']}: {result['filter']} filter, {result['controller']} controller, "
                 f"seed {scenario.seed}")
        wrote(plot_trajectory(traj, args.plot, title=title, summary=summary))
    if args.rrd:
        from testbed.outputs.viz import run_description, write_rrd

        model = traj.rig.model
        app = f"testbed/{meta['rig']}"
        path = write_rrd(traj, args.rrd, model=model, application_id=app,
                         description=run_description(meta, summary))
        wrote(path)
    if args.save_log:
        from testbed.experiment.replay import recording_from_result
        from testbed.io.formats import write_recording

        wrote(write_recording(args.save_log, recording_from_result(
            traj, source=os.path.basename(args.save_log))))
    if args.video:
        from testbed.outputs.render import frame_stride, iter_frames, write_video

        rig = traj.rig
        dt_s = traj.t_s[1] - traj.t_s[0]
        stride = frame_stride(dt_s)
        frames = iter_frames(rig, traj.state, stride)
        wrote(write_video(args.video, frames, 1.0 / (dt_s * stride)))
    if live is not None:
        from testbed.io import commit_outputs

        commit_outputs()  # the files are complete: they appear before serving goes on
        say_written()
        finish_live(args, live)
    return 0


def _cmd_run_realtime(args: argparse.Namespace, scenario: Scenario) -> int:
    """``testbed run --realtime``: the episode paced to the wall clock
    (testbed.experiment.realtime)."""
    from testbed.experiment.realtime import run_scenario

    for flag, value in (("--plot", args.plot), ("--rrd", args.rrd), ("--video", args.video)):
        if value:
            raise ValueError(f"{flag} is not available with --realtime (use --json)")
    factor = args.realtime_factor
    print(f"running {scenario.duration_s:g} s of simulated time paced at {factor:g}x real time")
    summary = run_scenario(scenario, factor)
    meta = summary.pop("meta")
    pacing = summary["pacing"]
    print(f"{meta['rig']} | filter {meta['scenario']['estimator']} | sensors {meta['sensors']} "
          f"| {pacing['steps']} steps in {pacing['wall_s']:.3f} s wall (target "
          f"{pacing['target_wall_s']:.3f} s, pacing error {100 * pacing['pacing_error']:+.2f} %)")
    print(f"overruns (late commands) {pacing['overruns']}, missed samples "
          f"{pacing['missed_samples']}, simulation overruns {pacing['sim_overruns']}, max "
          f"lateness {1e3 * pacing['max_lateness_s']:.2f} ms")
    print(format_table(summary, summary["units"]))
    if args.json:
        result = {"rig": meta["rig"], "seed": scenario.seed, **summary,
                  **scenario_and_meta(meta)}
        wrote(write_json(args.json, result))
    return 0


def scenario_and_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """The JSON's ``scenario`` block (what ``--scenario`` reads) and ``meta`` (the rest)."""
    return {"scenario": meta["scenario"], "meta": {k: v for k, v in meta.items()
                                                   if k != "scenario"}}
