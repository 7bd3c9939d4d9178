"""How long a run of each preset took, as measured: the one source of the README's "time per run
(CPU)" column (tests/core/test_preset_times.py holds the two equal) and of the submit form's
estimate (``GET /api/presets``).

Each figure names the CPU it was measured on and how (:data:`HOW_MEASURED`); a range is the spread
over the seeds run. A preset not timed here has no entry and reads :data:`NOT_MEASURED`: no figure is
made up from another preset's.
"""

from __future__ import annotations

from dataclasses import dataclass

#: How every figure below was measured (the README's "What the presets land" says the same).
HOW_MEASURED = "one torch thread per run, two runs at a time on a 2-core machine"
#: What a preset without a measurement says instead of a figure.
NOT_MEASURED = "not measured here"


@dataclass(frozen=True)
class RunTime:
    """One measured time per run: ``time`` (a figure or a range, with its unit and any condition of
    the measurement, e.g. "207-242 s training") on ``cpu`` (the CPU model, e.g. "AMD EPYC")."""

    time: str
    cpu: str

    def text(self) -> str:
        return f"{self.time} ({self.cpu})"


AMD, INTEL = "AMD EPYC", "Intel Xeon"

#: Preset name -> its measured times per run, one per CPU kind it was timed on.
PRESET_TIMES: dict[str, tuple[RunTime, ...]] = {
    "quick": (RunTime("68-75 s", AMD),),
    "diffsim-3x3x3": (RunTime("311-369 s", AMD),),
    "diffsim-5x5x5": (RunTime("352-378 s", AMD),),
    "trade-off-3x3x3": (RunTime("219-233 s training", AMD),),
    "trade-off-5x5x5": (RunTime("287-320 s training", AMD),),
    "trade-off-7x7x7": (RunTime("7.9 min", AMD),),
    "trade-off-10x10x10": (RunTime("9.1-13.6 min", AMD),),
    "cpu-3x3x3": (RunTime("42-44 min", AMD), RunTime("46.7 min", INTEL)),
    "quick-td3": (RunTime("9.4 min", AMD), RunTime("6.9 min", INTEL)),
}


def run_times(preset: str) -> tuple[RunTime, ...]:
    """The measured times of ``preset`` (empty: not measured)."""
    return PRESET_TIMES.get(preset, ())


def run_time_text(preset: str) -> str:
    """``preset``'s times as one line, "68-75 s (AMD EPYC)" (several joined by "; "), or
    :data:`NOT_MEASURED`: the README's cell."""
    times = run_times(preset)
    return "; ".join(t.text() for t in times) if times else NOT_MEASURED
