"""Every Taichi kernel and function takes at most 16 parameters: arrays travel in
their bundle's argument pack (``dem/state.py``), not one by one (issue 33); and
every task of a kernel a GPU run launches reads at most 31 arrays (issue 34)."""
import importlib
import inspect
import json
import subprocess
import sys
from pathlib import Path

import pytest

import taichi_hsdem
from conftest import precision
from taichi_hsdem import backend
from taichi_hsdem.backend import ti

MAX_PARAMS = 16
# Taichi 1.7.4 refuses a CPU launch whose arguments hold more than 64 elements (an
# argument pack counts itself and each member; kernel_impl.max_arg_num).
MAX_ELEMENTS = 64

ROOT = Path(taichi_hsdem.__file__).parent
KERNEL_MODULES = sorted(
    ".".join(("taichi_hsdem",) + p.relative_to(ROOT).with_suffix("").parts)
    for p in ROOT.rglob("*.py") if "@ti.kernel" in p.read_text() or "@ti.func" in p.read_text())


def taichi_callables(module):
    """(name, callable) of every kernel and ti.func defined in ``module``, in its
    classes too."""
    found = []
    scopes = [(module.__name__, vars(module))] + [
        (f"{module.__name__}.{c.__name__}", vars(c)) for c in vars(module).values()
        if inspect.isclass(c) and c.__module__ == module.__name__]
    for where, scope in scopes:
        for name, obj in scope.items():
            if ((getattr(obj, "_is_wrapped_kernel", False)
                 or getattr(obj, "_is_taichi_function", False))
                    and obj.__module__ == module.__name__):
                found.append((f"{where}.{name}", obj))
    return found


def elements(annotation) -> int:
    """Taichi's count of the argument elements an argument of this annotation takes."""
    if isinstance(annotation, ti.types.template):
        return 0
    if isinstance(annotation, ti.lang.argpack.ArgPackType):
        return 1 + sum(elements(a) for a in annotation.members.values())
    return 1


@pytest.mark.parametrize("module", KERNEL_MODULES)
def test_kernels_take_at_most_16_parameters(module):
    found = taichi_callables(importlib.import_module(module))
    assert found, f"{module} holds no Taichi kernel or function"
    wide = {name: len(inspect.signature(f).parameters) for name, f in found}
    assert max(wide.values()) <= MAX_PARAMS, {k: n for k, n in wide.items() if n > MAX_PARAMS}


def test_the_widest_dem_kernels_fit_taichis_argument_limit():
    from taichi_hsdem.dem import contact, fused, integrate, neighbors
    for kernel in (contact.ls_contacts, contact.disk_contacts, fused.steps,
                   integrate.advance_kernel, neighbors.build_neighbors):
        n = sum(elements(p.annotation) for p in inspect.signature(kernel).parameters.values())
        assert n <= MAX_ELEMENTS, (kernel.__name__, n)


def test_pack_member_names_are_unique_across_bundles():
    # Taichi 1.7.4 keys a kernel's packed arrays by member name alone
    from taichi_hsdem.dem import state
    with pytest.raises(TypeError, match=r"Other\.x: Bodies already has an array"):
        state.pack_type("Other", ("spare", "x"))
    assert "spare" not in state._MEMBER_OWNER   # nothing registered by a refused pack


def test_a_pack_follows_its_bundles_arrays():
    from taichi_hsdem.dem import state
    backend.init("cpu", precision())
    history = state.ShearHistory(1, 2, 1, 3)
    before = history.pack()
    assert history.pack() is before              # kept while nothing changed
    history.swap()
    after = history.pack()
    assert after["partners_old"] is before["partners_new"]
    assert after["shear_new"] is before["shear_old"]
    history.swap()
    assert history.pack() is before              # both orders kept (one swap a step)
    bodies = state.Bodies.zeros(1, 2)
    pack = bodies.pack()
    bodies.alive = state.array([[1, 0]], ti.i32)   # a replaced array: a new pack
    assert bodies.pack()["alive"] is bodies.alive and pack["alive"] is not bodies.alive


def test_a_part_packs_some_of_a_bundles_arrays():
    from taichi_hsdem.dem import state
    backend.init("cpu", precision())
    pose = state.Bodies.part("x", "alive")
    assert list(pose.members) == ["x", "alive"]
    bodies = state.Bodies.zeros(1, 2)
    part = bodies.pack_of(pose)
    assert part["x"] is bodies.x and bodies.pack_of(pose) is part   # kept
    bodies.alive = state.array([[1, 0]], ti.i32)
    assert bodies.pack_of(pose)["alive"] is bodies.alive            # follows a replaced array
    with pytest.raises(TypeError, match=r"Materials\.x: Bodies already has an array"):
        state.Materials.part("x")


# A GPU shader binds each array its task reads to a slot: Metal has 31; Mesa's
# Vulkan gives wrong results past 32 (docs/performance.md, Kernel launches).
MAX_ARRAYS = 31
# the kernels tests/kernel_arrays.py must see compiled (a GPU run's widest)
GPU_KERNELS = ("contact.ls_pair_contacts", "contact.ls_wall_contacts", "contact.disk_contacts",
               "integrate.advance_kernel", "coupling.rasterize_permeability",
               "coupling.body_drift", "coupling.pressure_forces", "neighbors.build_neighbors",
               "_gmg_cg._cg_step", "_gmg_cg._check_stopped", "_gmg_bodies._body_rhs")


def test_every_task_a_gpu_run_launches_reads_at_most_31_arrays():
    # Counted in Taichi's own IR of the kernels a GPU run launches (compiled on the
    # CPU, the GPU's kernel choices forced: tests/kernel_arrays.py). The CPU-only
    # kernels are wider and never run on a GPU: ls_contacts (34 arrays, split in
    # two there) and the fused disk stepper (42; refused on a GPU).
    proc = subprocess.run([sys.executable, str(Path(__file__).parent / "kernel_arrays.py")],
                          capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = json.loads(proc.stdout)
    ours = {k.removeprefix("taichi_hsdem."): v for k, v in counts.items()
            if k.startswith("taichi_hsdem.")}
    for name in GPU_KERNELS:
        assert any(k.endswith(name) for k in ours), (name, sorted(ours))
    assert all(0 < v <= MAX_ARRAYS for v in ours.values()), ours
    assert not any(k.endswith(("contact.ls_contacts", "fused.steps")) for k in ours)
