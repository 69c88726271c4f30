"""How many arrays each compiled Taichi kernel's tasks read: a script the tests
run in a subprocess (tests/test_kernel_signatures.py).

Vulkan and Metal bind each array a task (an offloaded loop, one compute shader)
reads to a buffer slot of that shader: Metal has 31, and Mesa's Vulkan gives wrong
results past 32 (docs/performance.md, Kernel launches). Taichi prints its IR with
``print_ir=True``; its last pass prints each task alone, where every array the
task reads is one ``argaddr[...]`` (a plain argument or an argument pack's
member). This runs small simulations on the CPU with the IR printed, marks where
each kernel compiles, and prints one JSON line: ``{kernel: most arrays one of its
tasks reads}``.

    python tests/kernel_arrays.py
"""
import json
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
MARK = "@@KERNEL "


def _exercise():
    """Every kernel a GPU run launches, once: the disk and level-set (the GPU's
    two kernels) per-step paths, the latter with the implicit carried volume and
    the multigrid solve's ``cells`` way."""
    import taichi.lang.kernel_impl as ki

    from taichi_hsdem import backend
    backend.init("cpu", "f64")
    ti = backend.ti
    cfg = ti.lang.impl.current_cfg()
    cfg.print_ir = True          # from the next compile on, and every kernel compiled
    cfg.offline_cache = False    # here (none from the cache, whose compiles print nothing)
    seen = set()
    launch = ki.Kernel.launch_kernel

    def marked(self, t_kernel, *args):
        if id(t_kernel) not in seen:
            seen.add(id(t_kernel))
            sys.stdout.flush()
            os.write(1, f"\n{MARK}{self.func.__module__}.{self.func.__name__}\n".encode())
        return launch(self, t_kernel, *args)

    ki.Kernel.launch_kernel = marked
    from taichi_hsdem.dem import contact
    from taichi_hsdem.fluid.gmg import TaichiPressureSolver
    contact.SPLIT_LS_CONTACTS = True       # the GPU's level-set kernels
    TaichiPressureSolver._choose_parallel = lambda self: "cells"   # and its solve
    from taichi_hsdem.scene import load_scene
    from taichi_hsdem.simulation import Simulation
    for scene, sets in ((ROOT / "scenes/vani_phi026.toml", {"run.stepping": "per_step",
                                                             "fluid.enabled": False,
                                                             "particles.0.kn": 0.1}),
                        (ROOT / "scenes/squares.toml", {"run.stepping": "per_step"})):
        values = {"run.realizations": 1, **sets}
        sc = load_scene(scene, overrides=[f"{k}={json.dumps(v)}" for k, v in values.items()])
        sim = Simulation(sc)
        if sim.fluid is not None:
            sim.update_fluid(force=True)
        step = getattr(sim, "advance", None) or sim.step
        step(3)
        if sim.fluid is not None:
            sim.update_fluid(force=True)


def count(lines) -> dict:
    """{kernel: most distinct arrays one of its tasks reads} from the marked IR
    output, line by line (it runs to hundreds of megabytes)."""
    found = {}
    name, blocks, block = None, [], None

    def close_block():
        if block is not None:
            blocks.append((block[0], len(block[1])))

    def close_kernel():
        close_block()
        # the last pass prints one task per block: the trailing run of such blocks
        most = 0
        for offloaded, arrays in reversed(blocks):
            if offloaded != 1:
                break
            most = max(most, arrays)
        if name is not None:
            found[name] = max(most, found.get(name, 0))

    for line in lines:
        if line.startswith(MARK):
            close_kernel()
            name, blocks, block = line[len(MARK):].strip(), [], None
        elif line.startswith("kernel {"):
            close_block()
            block = [0, set()]
        elif block is not None:
            if "= offloaded" in line:
                block[0] += 1
            if "argaddr[" in line:
                block[1].update(re.findall(r"argaddr\[[^\]]*\]", line))
    close_kernel()
    return found


def main():
    if "--child" in sys.argv:
        _exercise()
        return
    import subprocess
    import tempfile
    with tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen([sys.executable, __file__, "--child"], stdout=subprocess.PIPE,
                                stderr=err, text=True, errors="replace")
        found = count(proc.stdout)
        if proc.wait(timeout=1200):
            err.seek(0)
            sys.exit(err.read()[-3000:])
    print(json.dumps(found, sort_keys=True))


if __name__ == "__main__":
    main()
