"""The main job: derive -> tune -> simulate -> identify -> diagnose -> export, into a report folder."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

__all__ = ["PipelineResult", "run_pipeline"]


@dataclass(frozen=True, slots=True)
class PipelineResult:
    """What the pipeline wrote.

    Attributes
    ----------
    out_dir : Path
        The report folder.
    steps : dict
        Per step: ``{"seconds": float, "files": [...], "summary": {...}}``.
    """

    out_dir: Path
    steps: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_mapping(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"out_dir": str(self.out_dir), "steps": self.steps}


def _dump(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2, allow_nan=True) + "\n")


def _derive(out: Path) -> dict[str, Any]:
    from .params import Design
    from .plotting.bode import plot_bode
    from .symbolic import transfer_functions

    tfs = {name: transfer_functions(Design.nominal(name)) for name in ("soft", "stiff", "exp-soft", "locked")}
    _dump(out / "tf.json", {name: t.to_mapping() for name, t in tfs.items()})
    plot_bode([(f"P ({name})", t.P.tf) for name, t in tfs.items()]
              + [(f"P_n^{key} (stiff)", getattr(tfs["stiff"], key).tf) for key in ("EA", "LO", "LD")],
              out / "bode.png", title="Force plant P in four environments and the nominal plants")
    return {"files": ["tf.json", "bode.png"],
            "summary": {name: {"dc_gain": t.P.tf.dcgain(), "order": len(t.P.tf.den) - 1} for name, t in tfs.items()}}


def _tune(out: Path) -> dict[str, Any]:
    from .analysis import fig6_table
    from .plotting.margins import plot_fig6
    from .tuning import tune_q

    rows = fig6_table()
    _dump(out / "fig6.json", [r.to_mapping() for r in rows])
    plot_fig6(rows, out / "fig6.png")
    tuned = {obs: tune_q(obs, "soft,stiff", min_ratio=0.9, band_hz=(0.5, 30.0)).to_mapping()
             for obs in ("ea-fob", "lo-dob", "ld-dob")}
    _dump(out / "tune_q.json", tuned)
    return {"files": ["fig6.json", "fig6.png", "tune_q.json"],
            "summary": {obs: r["w_q_hz"] for obs, r in tuned.items()}}


_STEPS: list[tuple[str, str, Callable[[Path], dict[str, Any]]]] = [
    ("derive", "Symbolic transfer functions (eqs. 2-8)", _derive),
    ("tune", "Disk margins (Fig. 6) and Q-cutoff tuning", _tune),
]


def run_pipeline(out_dir: str | Path = "report", *, progress: Callable[[str], None] | None = None) -> PipelineResult:
    """Run every step on the bundled defaults and write a Markdown report with plots.

    Parameters
    ----------
    out_dir : str or Path
        Report folder (created).
    progress : callable, optional
        Called with each step's name before it runs.

    Returns
    -------
    PipelineResult
        Files and summaries per step; ``out_dir/index.md`` links them all.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = PipelineResult(out)
    lines = ["# forecast_design report", ""]
    for name, title, step in _STEPS:
        if progress:
            progress(name)
        start = time.perf_counter()
        info = step(out)
        info["seconds"] = round(time.perf_counter() - start, 3)
        result.steps[name] = info
        lines += [f"## {name}: {title}", "", f"({info['seconds']} s)", ""]
        for f in info["files"]:
            lines.append(f"![{f}]({f})" if f.endswith(".png") else f"- [{f}]({f})")
        lines += ["", "```json", json.dumps(info["summary"], indent=2), "```", ""]
    (out / "index.md").write_text("\n".join(lines))
    _dump(out / "summary.json", result.to_mapping())
    return result
