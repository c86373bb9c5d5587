"""``nrtraffic compare``: finished runs of one scenario side by side (:mod:`nrtraffic.compare`)."""

from __future__ import annotations

import sys
from pathlib import Path


OUTPUTS = ("compare.html", "compare_runs.csv", "compare_movements.csv", "compare_approaches.csv")


# how each of compare's files begins (its report: the generator nrtraffic's pages name)
OWN_START = {"compare.html": None, "compare_runs.csv": "run,control,", "compare_movements.csv": "approach,movement,run,",
             "compare_approaches.csv": "approach,run,control,"}


def _written_by_compare(path: Path) -> bool:
    """Whether ``path`` is one of compare's files as compare writes them (its report names
    nrtraffic as its generator; its tables begin with their header)."""
    from nrtraffic.report import GENERATOR

    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", "replace")
    except OSError:
        return False
    start = OWN_START[path.name]
    return GENERATOR in head if start is None else head.startswith(start)


def main(args) -> int:
    """Compare ``args.run_dirs``; write the report into ``args.out`` (default
    ``runs/<scenario>-compare``) and print it. Exit status 2, with the reason, when the run
    directories cannot be compared or the output folder cannot be used."""
    from nrtraffic.compare import CompareError, compare, console, write
    from runners.api import OutputError, slug, writable_dir
    from runners.single import in_a_run, in_a_sweep, is_run_dir

    try:
        c = compare(args.run_dirs)
        out = args.out or Path("runs") / f"{slug(c.scenario)}-compare"
        inside = Path(out) if is_run_dir(out) else in_a_run(out)
        if inside is not None:  # (its files would be taken for the run's own)
            where = "a run directory" if inside == Path(out) else f"in the run directory {inside}"
            raise OutputError(f"--out {out}: {where}; write the comparison into another folder")
        owner = in_a_sweep(Path(out))
        if owner is not None:  # (its files there would stop the sweep's resume, which keeps its folder its own)
            raise OutputError(f"--out {out} lies in the sweep folder {owner}: write the comparison into a folder "
                              "outside it")
        ours = [n for n in OUTPUTS if (Path(out) / n).exists()]
        mine = [n for n in ours if not (Path(out) / n).is_symlink() and not _written_by_compare(Path(out) / n)]
        if mine:  # (--force replaces an earlier comparison's files, never a file of the user's of that name)
            raise OutputError(f"--out {out} holds {', '.join(mine)}, which no comparison wrote (a file of your "
                              "own, or a comparison's of an earlier version): choose another folder, or move it")
        if ours and not args.force:
            raise OutputError(f"--out {out} already holds {', '.join(ours)}: choose another folder, or --force to "
                              "replace them (nothing else in it is touched)")
        writable_dir(out)
        for n in OUTPUTS:  # (a link of that name is replaced, never written through to where it points)
            if (Path(out) / n).is_symlink():
                (Path(out) / n).unlink()
        paths = write(c, out)
    except (CompareError, OutputError) as exc:
        print(f"nrtraffic: {exc}", file=sys.stderr)
        return 2
    print(console(c), end="")
    print(f"report: {paths[0]}; tables: " + ", ".join(str(p) for p in paths[1:]))
    return 0
