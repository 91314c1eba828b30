"""``qchain fit FIT.toml``: the command over :mod:`qchain.fit` (read and check the fit file
and its experiments, fit, print the table and the warnings, write ``fitted.toml``,
``fit.json`` and ``fit.png``). The file's format: ``docs/fit.md`` (:mod:`qchain.fit.spec`).

Exit codes as the other commands' (``docs/cli.md``): 0 the fit ran (also one that did not
converge: said as a warning and in ``fit.json``), 1 it failed or was interrupted, 2 a fit
file, scene or experiment refused before it started. Nothing is written before the fit has
ended, and each output whole or not at all: a refused or failed fit leaves the output folder
as it was."""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import warnings
from contextlib import suppress

from ..checks.text import printable, show_path
from .checks import check_output_folder, path_argument
from .command import command
from .errors import BadInput, take_debug

__all__ = ["main", "OUTPUTS"]

#: What a fit writes into its folder.
OUTPUTS = ("fitted.toml", "fit.json", "fit.png")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="qchain fit", description="Fit a scene's parameters to measured experiments "
                                "(ROS 2 bags, qchain recordings, CSV files) as a fit file says (format: docs/fit.md); "
                                "write the fitted scene, fit.json and fit.png.")
    p.add_argument("fit", type=path_argument, help="the fit file (.toml)")
    p.add_argument("--out", type=path_argument, default=None, metavar="DIR",
                   help="output folder, instead of the file's [output] folder")
    p.add_argument("--no-plot", action="store_true", help="write no fit.png")
    return p


def main(argv=None, *, debug: bool | None = None, session=None) -> int:
    """``qchain fit FIT.toml [...]`` (``argv``: the arguments after ``fit``) -> the exit code."""
    argv = [os.fspath(a) for a in (sys.argv[1:] if argv is None else argv)]
    if debug is None:
        argv, debug = take_debug(argv)
    return command("fit", lambda s: _main(argv, s), bool(debug), session)


def _main(argv: list[str], session) -> int:
    from ..fit.spec import load_fit_spec

    args = _parser().parse_args(argv)
    with warnings.catch_warnings(record=True) as read_warnings:  # the readers' warnings: said, and kept in fit.json
        warnings.simplefilter("always")
        spec = load_fit_spec(args.fit, out=args.out)
    spec.read_warnings = [str(w.message) for w in read_warnings]
    made = not spec.folder.exists()
    check_output_folder("the output folder", spec.folder)
    try:
        return _fit(spec, args, session)
    except BaseException:
        if made:  # a folder this command made and wrote nothing into: gone again
            with suppress(OSError):
                spec.folder.rmdir()
        raise


def _fit(spec, args, session) -> int:
    """Fit, print, write the outputs (after the fit: whole or not at all)."""
    from ..fit.fitting import fit
    from ..fit.measurements import MeasurementError

    said = spec.read_warnings
    for text in said:
        print(printable(f"qchain fit: warning: {' '.join(text.split())}"), file=sys.stderr)
    print(printable(f"fit {show_path(spec.path)}: {len(spec.keys)} parameters of {show_path(spec.scene)} from "
                    f"{len(spec.experiments)} experiment(s); results in {show_path(spec.folder)}"))
    sys.stdout.flush()
    session.phase = "run"
    with warnings.catch_warnings(record=True) as fit_warnings:
        warnings.simplefilter("always")
        try:
            rep = fit(spec.scene, spec.experiments, spec.keys, bounds=spec.bounds, values=spec.values,
                      **spec.options)
        except MeasurementError as err:  # the experiments against the model (chambers, reach, too few): input
            raise BadInput(f"{show_path(spec.path)}: {err}") from None
    fitted = [str(w.message) for w in fit_warnings]
    session.phase = "end"
    for line in rep.summary():
        print(printable(line))
    for text in fitted:
        print(printable(f"qchain fit: warning: {' '.join(text.split())}"), file=sys.stderr)
    data = rep.to_dict()
    data["fit_file"] = str(spec.path)
    data["warnings"] = said + fitted
    files = {"fitted.toml": rep.scene_text().encode(), "fit.json": (json.dumps(data, indent=1) + "\n").encode()}
    if spec.plot and not args.no_plot:  # drawn in memory first: nothing is written unless every output is made
        buf = io.BytesIO()
        fig = rep.plot()
        fig.savefig(buf, format="png", dpi=fig.dpi)
        files["fit.png"] = buf.getvalue()
    _write(spec.folder, files)
    for name in files:
        print(printable(f"wrote {show_path(spec.folder / name)}"))
    return 0


def _write(folder, files: dict) -> None:
    """Each file whole or not at all (:func:`qchain.checks.paths.written_whole`)."""
    from ..checks.paths import written_whole

    for name, data in files.items():
        with written_whole(folder / name, binary=True, prefix=".fit-") as fh:
            fh.write(data)
