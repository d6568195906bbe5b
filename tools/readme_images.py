"""Draw the README's pictures (docs/images/) with the commands a user types, one per capability.

Run from the repository root: ``.venv/bin/python tools/readme_images.py`` (a few minutes: the benchmark
runs 48 simulations).
Each picture is the ``--plot`` (or report) PNG of the command listed in ``PICTURES``, made in a
temporary folder and written to ``docs/images/`` scaled to at most ``MAX_WIDTH_PX`` pixels wide
and reduced to a 256-colour palette, so the set stays small in the repository.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "images"
MAX_WIDTH_PX = 1100

# An open-loop identification run that slides through several revolutions (angle-dependent friction)
IDENTIFICATION_SCENARIO = """\
format = "forecast-scenario/1"
description = "open-loop multisine torque, angle-dependent friction (identification run)"
environment = "link-only"

[sampling]
rate_hz = 2000.0

[testbed]
J_m = 0.133
d_m = 0.3
k = 58.0

[[truth.effects]]
effect = "position_friction"
F_c = 0.4
a = [0.05, 0.02]
b = [0.03, 0.0]

[reference]
kind = "multisine"
amplitudes = [1.5, 0.3]
frequencies_hz = [0.2, 3.0]
offset = 0.8

[simulation]
duration_s = 20.0
seed = 5
"""

# (file in docs/images, what it shows, the command's arguments, the PNG it writes in the work folder)
PICTURES = (
    ("tf.png", "P and the nominal plants per environment",
     ["tf", "--env", "soft,stiff,locked", "--plot", "{w}/tf.png"], "tf.png"),
    ("margins.png", "disk and classical margins of one loop",
     ["margins", "--controller", "pid:6:20:0.05:0.002", "--compensator", "ea-fob", "--env", "exp-soft",
      "--plot", "{w}/margins.png"], "margins.png"),
    ("fig6.png", "the paper's Fig. 6", ["reproduce", "fig6", "--plot", "{w}/fig6.png"], "fig6.png"),
    ("tune_q.png", "the Q cutoff's trade-off",
     ["tune-q", "--observer", "lo-dob", "--envs", "soft,stiff", "--plot", "{w}/tune_q.png"], "tune_q.png"),
    ("simulate.png", "a simulated run",
     ["simulate", "{root}/forecast_design/data/example_scenario.toml", "--out", "{w}/run/run.toml",
      "--plot", "{w}/simulate.png"], "simulate.png"),
    ("identify.png", "friction identified from a log",
     ["identify", "{w}/id/id.toml", "--model", "position-friction", "--harmonics", "2", "--plot", "{w}/identify.png"], "identify.png"),
    ("fig7.png", "the paper's Fig. 7 on the virtual testbed",
     ["reproduce", "fig7", "--plot", "{w}/fig7.png"], "fig7.png"),
    ("benchmark.png", "a benchmark over an environment set",
     ["benchmark", "--envs", "soft,stiff,exp-soft,locked", "--repetitions", "4", "--out", "{w}/bench"],
     "bench/heatmap.png"),
    ("diagnose.png", "the sim-to-real gap diagnosis",
     ["diagnose", "{w}/run/run.toml", "--report", "{w}/diagnosis"], "diagnosis/before_after.png"),
    ("passivity.png", "the port's passivity (stable with every passive environment?)",
     ["passivity", "--compensator", "ea-fob", "--w-q-hz", "10", "--env", "soft", "--plot", "{w}/passivity.png"],
     "passivity.png"),
)


def _shrink(src: Path, dst: Path) -> None:
    from PIL import Image

    with Image.open(src) as im:
        im = im.convert("RGB")
        if im.width > MAX_WIDTH_PX:
            im = im.resize((MAX_WIDTH_PX, round(im.height * MAX_WIDTH_PX / im.width)), Image.LANCZOS)
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(dst, optimize=True)


def main() -> int:
    """Run every command of ``PICTURES`` and write its picture to docs/images; returns the exit code."""
    from forecast_design.cli import main as cli

    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "id").mkdir()
        (work / "id" / "scenario.toml").write_text(IDENTIFICATION_SCENARIO)
        with contextlib.redirect_stdout(io.StringIO()):
            if cli(["simulate", str(work / "id" / "scenario.toml"), "--out", str(work / "id" / "id.toml")]) != 0:
                return 1
        for name, what, argv, made in PICTURES:
            args = [a.format(w=work, root=ROOT) for a in argv]
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
                code = cli(args)
            if code not in (0, 1) or not (work / made).exists():   # margins/diagnose exit 1 on a finding
                print(f"readme_images: {name} ({what}): forecast-design {' '.join(argv)} exited {code}: "
                      f"{err.getvalue().strip()}", file=sys.stderr)
                return 1
            _shrink(work / made, OUT / name)
            print(f"{OUT.relative_to(ROOT) / name}: {what} ({(OUT / name).stat().st_size // 1024} kB)")
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
