"""Running a scene on a user's behalf: build the simulation, run it, and turn what can
go wrong into lines in the user's terms. The command line, sweeps, figures and the
calibration all go through here, so a failure reads the same everywhere.

* :func:`build`: a :class:`~taichi_hsdem.simulation.Simulation`, or
  :class:`RunFailed` with ``kind = "invalid"`` (the scene or the backend cannot
  work: the command line exits 2).
* :func:`execute`: the run's :class:`~taichi_hsdem.simulation.Result`, or
  :class:`RunFailed` with ``kind = "failed"`` (the pressure solve did not balance,
  or the run itself failed: exit 1).
* :func:`unstable_message`: what to say about realizations that went unstable.
"""
from __future__ import annotations

from . import backend
from .fluid import FluxImbalanceError
from .scene import Scene, SceneError
from .simulation import Result, RunError, Simulation

#: What to change when a realization goes numerically unstable.
UNSTABLE_HINT = ("lower run.dt (or run.dt_safety), raise the particles' kn, or lower the "
                 "driving pressure / flow rate")
#: The same when the scene sets run.dt itself: a stiffer contact would only lower
#: the critical time step further below it.
UNSTABLE_HINT_FIXED_DT = ("lower run.dt (or set it to \"auto\": the contacts' critical "
                          "step times run.dt_safety), or lower the driving pressure / "
                          "flow rate")
#: What to change when a pressure solve does not conserve mass.
FLUX_HINT = "tighten fluid.solver_tol or refine fluid.cell_size"


def unstable_hint(scene) -> str:
    """What to change when realizations of ``scene`` went unstable."""
    return UNSTABLE_HINT if scene.run.dt == "auto" else UNSTABLE_HINT_FIXED_DT


class RunFailed(Exception):
    """A scene could not be run; ``kind`` is ``"invalid"`` or ``"failed"`` and
    ``lines`` the messages, one per problem."""

    def __init__(self, kind: str, lines: list[str]):
        self.kind = kind
        self.lines = list(lines)
        super().__init__("; ".join(self.lines))


def build(scene: Scene, **options) -> Simulation:
    """``Simulation(scene, **options)``; a scene or backend that cannot work raises
    :class:`RunFailed` (``"invalid"``)."""
    try:
        backend.refuse_software_gpu(scene.run.arch, scene.run.precision)
        return Simulation(scene, **options)
    except SceneError as exc:
        raise RunFailed("invalid", exc.problems) from None
    except backend.AddressSpaceLimit as exc:
        raise RunFailed("invalid", [str(exc)]) from None
    except backend.BackendError as exc:
        raise RunFailed("invalid", [f"{scene.source}: run.arch: {exc}"]) from None


def execute(sim: Simulation, **run_options) -> Result:
    """``sim.run(**run_options)``; a pressure solve that does not balance or a run
    error raises :class:`RunFailed` (``"failed"``) with what to change."""
    try:
        return sim.run(**run_options)
    except FluxImbalanceError as exc:
        raise RunFailed("failed", [f"the pressure solve did not conserve mass ({exc}); "
                                   f"{FLUX_HINT}"]) from None
    except RunError as exc:
        raise RunFailed("failed", [str(exc)]) from None


def unstable_message(result: Result) -> str | None:
    """One line naming the realizations that went unstable and what to change, or
    None when all ran stably."""
    bad = [r for r in result.summary["realizations"] if r["status"] == "unstable"]
    if not bad:
        return None
    return (f"{len(bad)} realization(s) went unstable (seeds "
            f"{', '.join(str(r['seed']) for r in bad)}): {unstable_hint(result.scene)}")
