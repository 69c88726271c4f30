"""taichi_hsdem: level-set DEM particles in a Hele-Shaw flow, clogging constrictions.

The method, in the order of the package: scene (:mod:`.scene`) -> shapes and walls
(:mod:`.geometry`) -> resolved set-up (:mod:`.resolve`) -> contact, fluid coupling
and integration in Taichi (:mod:`.dem`) with the pressure solve (:mod:`.fluid`) ->
the run (:mod:`.simulation`) and its observables (:mod:`.observables`, into a
:mod:`.runstate`) -> statistics (:mod:`.stats`) -> output and rendering
(:mod:`.output`, :mod:`.render`, :mod:`.paraview`).

Examples
--------
>>> import taichi_hsdem as th
>>> scene = th.load_scene("scenes/hourglass24.toml", ["run.t_end=1.0"])  # doctest: +SKIP
>>> result = th.run(scene)                                               # doctest: +SKIP
>>> result.summary["mean_escapees"]                                      # doctest: +SKIP
"""
from .version import __version__

from .scene import Scene, SceneError, load_scene, scene_to_toml  # noqa: E402

_LAZY = ("Result", "RunError", "Simulation")


def __getattr__(name):
    # The simulator imports Taichi (about a second); the pressure-solver worker
    # processes (:mod:`.fluid.worker`) import this package and never need it.
    if name in _LAZY:
        from . import simulation
        return getattr(simulation, name)
    raise AttributeError(f"module 'taichi_hsdem' has no attribute {name!r}")


def run(scene, overrides=(), progress=None, on_phase=None):
    """Load (if needed) and run a scene; return its :class:`Result`.

    ``scene`` is a :class:`Scene`, a path to a TOML file or a dict. ``progress(t,
    t_end)`` is called as the run goes on, ``on_phase(what)`` as each phase of the
    set-up begins (10-30 s on a first run, while Taichi compiles), e.g. ``print``.
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene, overrides)
    elif overrides:
        raise TypeError("overrides apply to a path or dict; use load_scene(...) for a Scene")
    from .simulation import Simulation
    return Simulation(scene, on_phase=on_phase).run(progress=progress)


__all__ = ["Scene", "SceneError", "load_scene", "scene_to_toml", "Simulation", "Result",
           "RunError", "run", "__version__"]
