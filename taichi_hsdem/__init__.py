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

# Every name below is imported on first use: the simulator imports Taichi (about a
# second), the scene numpy (a few tenths); the pressure-solver worker processes
# (:mod:`.fluid.worker`) need neither, and ``python -m taichi_hsdem`` installs its
# signal handlers before either loads, so that a Ctrl-C or SIGTERM at any moment
# of the set-up is answered with one line.
_LAZY = {"Scene": "scene", "SceneError": "scene", "load_scene": "scene",
         "scene_to_toml": "scene", "Result": "simulation", "RunError": "simulation",
         "Simulation": "simulation"}


def __getattr__(name):
    if name in _LAZY:
        from importlib import import_module
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'taichi_hsdem' has no attribute {name!r}")


def run(scene, overrides=(), progress=None, on_phase=None):
    """Load (if needed) and run a scene; return its :class:`Result`.

    ``scene`` is a :class:`Scene`, a path to a TOML file or a dict. ``progress(t,
    t_end)`` is called as the run goes on, ``on_phase(what)`` as each phase of the
    set-up begins (10-30 s on a first run, while Taichi compiles), e.g. ``print``.
    """
    from .scene import Scene, load_scene
    if not isinstance(scene, Scene):
        scene = load_scene(scene, overrides)
    elif overrides:
        raise TypeError("overrides apply to a path or dict; use load_scene(...) for a Scene")
    from .simulation import Simulation
    return Simulation(scene, on_phase=on_phase).run(progress=progress)


__all__ = ["Scene", "SceneError", "load_scene", "scene_to_toml", "Simulation", "Result",
           "RunError", "run", "__version__"]
