"""``python -m testbed.runtime.recording_service --report RECORDER-ARGS``: the recorder as deployed.

Runs ``python -m recorder`` with the same arguments in this process; when it
has finished the MCAP file (on SIGTERM, e.g. ``docker compose down``), writes
``report.md``, ``summary.json`` and the plots beside it with ``--report``. This
is what ``formation run`` does from the launcher, done by the recorder's own
container so that stopping the deployment loses nothing and leaves the report.
``--host-out DIR`` names the run directory as the host sees it (``runs/<RUN_ID>``,
not ``/app/runs/...``) in the report and in what this prints.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path, PurePosixPath

from recorder import main as recorder_main  # this module has its own main
from recorder import read_run, recorder_parser


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m testbed.runtime.recording_service",
        description=__doc__.split("\n")[0] if __doc__ else None,
        add_help=False,
    )
    p.add_argument("--report", action="store_true", help="write report.md after the recording")
    p.add_argument(
        "--host-out", help="the run directory as the host names it (for the report's text)"
    )
    ours, rest = p.parse_known_args(sys.argv[1:] if argv is None else argv)
    args = recorder_parser().parse_args(rest)  # exits with the recorder's usage on bad args
    code = recorder_main(rest)
    if code != 0 or not ours.report:
        return code
    # Imported only now: the recording process starts without matplotlib (the report's plots).
    from recorder import write_report_from

    out_dir = Path(args.out or Path("runs") / args.run_id)
    shown = PurePosixPath(ours.host_out or out_dir)  # what the host calls out_dir
    try:
        run = replace(read_run(out_dir / args.file), source=str(shown / args.file))
        write_report_from([run], out_dir)  # titled as a local run's; the host's path under Runs
    except Exception as exc:  # the recording is safe; say why the report is not
        print(
            f"recording_service: error: no report for {shown / args.file}: {exc}", file=sys.stderr
        )
        return 1
    print(f"recording_service: report {shown / 'report.md'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
