"""The Taichi arrays of a batch of realizations, in bundles named for what they hold.

Built on the host from the resolved :class:`~taichi_hsdem.resolve.Model`; the
kernel modules' wrappers (``contact.add_forces``, ``integrate.advance``, ...)
take these bundles and hand their arrays to the kernels.

* :class:`Bodies`: the state of every body, ``(R, N)`` (realization, particle).
* :class:`Batch`: per-realization status, ``(R,)``.
* :class:`Particles`: what is constant per particle, ``(N,)`` (the same in every
  realization).
* :class:`Materials`: the contact law of every species pair and of every species
  against the walls, per-species damping and permeability.
* :class:`Templates`: every shape template's level-set grid, stacked in one flat
  array with per-template offset, shape and spacing, and its surface nodes.
* :class:`WallGrid`: the walls' level set.
* :class:`ShearHistory`: the double-buffered shear of every contact.

Each bundle hands its arrays to a kernel as one argument: ``bundle.pack()`` is a
Taichi argument pack (``ti.types.argpack``) of type ``Bundle.Pack`` whose members
are the bundle's arrays under their own names, so a kernel reads
``bodies.x[r, i]`` and adding an array to a bundle is one line here.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .. import backend
from ..backend import ti
from ..geometry import distance, levelset
from ..geometry import shapes as shp
from ..resolve import pair_table, wall_table
from .. import layout
from ..layout import DISK_HISTORY_SLOTS, LS_HISTORY_SLOTS



def array(data, dtype=None):
    """A Taichi ndarray holding ``data`` (real numbers unless ``dtype`` = ti.i32)."""
    real = backend.real()
    dtype = real if dtype is None else dtype
    data = np.ascontiguousarray(data)
    a = ti.ndarray(dtype, shape=data.shape)
    a.from_numpy(data.astype(backend.numpy_real() if dtype is real else np.int32))
    return a


def _zeros(shape, dtype=None, vector=False):
    real = backend.real()
    a = (ti.Vector.ndarray(2, real, shape=shape) if vector
         else ti.ndarray(real if dtype is None else dtype, shape=shape))
    a.fill(0)
    return a


#: The annotation of a bundle's field that is a Taichi array the kernels read (it
#: goes into the bundle's pack); other fields stay on the host.
Array = object

# Argument-pack member name -> the bundle that owns it. Taichi 1.7.4 declares the
# arrays of a kernel's argpack arguments by member name alone: two packs of one
# kernel holding arrays of the same name fail to compile, or hand one the other's
# array, so every name is unique across bundles. It also counts the members as the
# kernel's own arguments: a kernel (not a ti.func) cannot assign a local variable
# of a member's name ("Kernel argument ... is immutable").
_MEMBER_OWNER: dict = {}


def pack_type(owner: str, names) -> object:
    """The argpack type of the arrays ``names`` of bundle ``owner``; raises
    TypeError if another bundle already uses one of the names."""
    for name in names:
        if _MEMBER_OWNER.get(name, owner) != owner:
            raise TypeError(f"{owner}.{name}: {_MEMBER_OWNER[name]} already has an array "
                            f"of that name (pack members must be unique across bundles)")
    _MEMBER_OWNER.update(dict.fromkeys(names, owner))
    # untyped members: the kernels compile once per real type, as with plain arguments
    return ti.types.argpack(**{name: ti.types.ndarray() for name in names})


class Bundle:
    """Arrays that the kernels take as one argument of type ``Pack``.

    :meth:`pack` builds the argument pack once and keeps it (building one costs
    about as much as a kernel launch), again when an array is replaced (a grown
    neighbour list) and for each order of :class:`ShearHistory`'s two buffers.
    """
    Pack = None

    def arrays(self) -> dict:
        """The pack's members by name."""
        return {name: getattr(self, name) for name in self.Pack.members}

    def pack(self):
        """The argument pack of the bundle's arrays as they are now."""
        arrays = self.arrays()
        key = tuple(map(id, arrays.values()))
        packs = self.__dict__.setdefault("_packs", {})
        if key not in packs:
            if len(packs) > 1:
                packs.clear()
            packs[key] = self.Pack(**arrays)
        return packs[key]

    @classmethod
    def part(cls, *names) -> object:
        """The argpack type of some of the bundle's arrays, for a kernel that reads
        few of them and runs often enough that passing the others would cost: a
        launch costs about 3.5 us per array, packed or not."""
        return pack_type(cls.__name__, names)

    def pack_of(self, part):
        """The argument pack of type ``part`` (from :meth:`part`) of the bundle's
        arrays as they are now; kept as :meth:`pack` keeps its pack."""
        arrays = {name: getattr(self, name) for name in part.members}
        key = (id(part),) + tuple(map(id, arrays.values()))
        packs = self.__dict__.setdefault("_parts", {})
        if key not in packs:
            if len(packs) > 7:   # a few parts, each with its arrays of now
                packs.clear()
            packs[key] = part(**arrays)
        return packs[key]


def bundle(cls):
    """Make ``cls`` a dataclass and a :class:`Bundle` whose pack holds its
    ``Array`` fields."""
    cls = dataclass(cls)
    cls.Pack = pack_type(cls.__name__, [f.name for f in fields(cls) if f.type == "Array"])
    return cls


def _grid_gradient(phi: np.ndarray, h: float) -> np.ndarray:
    """Central-difference gradient of an x-first grid, flattened to (nx*ny, 2)."""
    gx, gy = np.gradient(phi, h)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


@bundle
class Bodies(Bundle):
    """State of every body, ``(R, N)``; ``force``/``torque`` are the last step's
    resultants, ``f_fluid``/``tau_fluid`` the pressure force held between
    evaluations, ``f_ext``/``tau_ext`` external loads (zero unless set)."""
    x: Array
    theta: Array
    v: Array
    omega: Array
    force: Array
    torque: Array
    f_fluid: Array
    tau_fluid: Array
    f_ext: Array
    tau_ext: Array
    alive: Array

    @classmethod
    def zeros(cls, R: int, N: int) -> "Bodies":
        shape = (R, N)
        return cls(x=_zeros(shape, vector=True), theta=_zeros(shape),
                   v=_zeros(shape, vector=True), omega=_zeros(shape),
                   force=_zeros(shape, vector=True), torque=_zeros(shape),
                   f_fluid=_zeros(shape, vector=True), tau_fluid=_zeros(shape),
                   f_ext=_zeros(shape, vector=True), tau_ext=_zeros(shape),
                   alive=_zeros(shape, ti.i32))


@bundle
class Batch(Bundle):
    """Per realization, ``(R,)``: ``running`` (1 while it runs), ``escaped`` (bodies
    past the escape line), ``bad`` (``layout.BAD_*`` bits), ``max_overlap``
    (deepest overlap since the last check, fraction of d_eq); ``status``: where
    ``integrate.read_status`` gathers them for the host."""
    running: Array
    escaped: Array
    bad: Array
    max_overlap: Array
    status: Array

    @classmethod
    def start(cls, R: int) -> "Batch":
        return cls(running=array(np.ones(R, dtype=np.int32), ti.i32),
                   escaped=_zeros(R, ti.i32), bad=_zeros(R, ti.i32), max_overlap=_zeros(R),
                   status=_zeros((4, R)))


@bundle
class Particles(Bundle):
    """Constant per particle, ``(N,)``: species (which is also the shape template's
    index: one template per species), mass, moment of inertia, spin drag over
    inertia (``spin``, 1/s: the rate at which the viscous torque beyond the global
    damping slows its spin), plate friction limit over mass (``plate``, N/kg, 0
    without plate contact) and the speed below which it turns viscous (``creep``,
    m/s), equivalent diameter, disk radius (the analytic path) and bounding
    radius."""
    species: Array
    mass: Array
    inertia: Array
    spin: Array
    plate: Array
    creep: Array
    d_eq: Array
    disk_radius: Array
    bounding_radius: Array
    species_np: np.ndarray

    @classmethod
    def of(cls, model) -> "Particles":
        spp = model.species_of_particle
        sp = model.species

        def per_particle(value):
            return array(np.array([value(sp[k]) for k in spp]))

        return cls(species=array(spp, ti.i32), mass=per_particle(lambda s: s.mass),
                   inertia=per_particle(lambda s: s.inertia),
                   spin=per_particle(lambda s: s.spin_drag / s.inertia),
                   plate=per_particle(lambda s: s.plate),
                   creep=per_particle(lambda s: s.creep),
                   d_eq=per_particle(lambda s: s.d_eq),
                   disk_radius=per_particle(lambda s: s.shape.radius),
                   bounding_radius=per_particle(lambda s: s.shape.bounding_radius),
                   species_np=spp)


#: What the contact kernels read of the particles: the integrator's own
#: per-particle rates stay out of their argument lists (Taichi's x64 backend takes
#: at most 64 argument elements a kernel).
CONTACT_PARTICLES = Particles.part("species", "mass", "d_eq", "disk_radius",
                                   "bounding_radius")


@bundle
class Materials(Bundle):
    """``pair`` (S, S, N_PAIR) and ``wall`` (S, N_PAIR): kn, ks, mu, c_e
    (``layout.PAIR_*``); ``xi`` (S,) global damping; ``kappa`` (S,) permeability
    inside a particle of the species; ``carry`` (S,) the share of its velocity a
    particle's cells carry in the pressure solve."""
    pair: Array
    wall: Array
    xi: Array
    kappa: Array
    carry: Array

    @classmethod
    def of(cls, model) -> "Materials":
        sp = model.species
        return cls(pair=array(pair_table(sp)), wall=array(wall_table(sp)),
                   xi=array(np.array([s.xi for s in sp])),
                   kappa=array(np.array([s.kappa for s in sp])),
                   carry=array(np.array([s.carried for s in sp])))


@bundle
class Templates(Bundle):
    """Every template's level-set grid in one flat array (``ls_meta[t]``: offset,
    nx, ny; ``ls_geo[t]``: origin x, origin y, spacing) with its central-difference
    gradient; surface nodes in body frame (``node_meta[t]``: offset, count) with
    their outward boundary vectors ``node_area``; ``inside`` (T, 2) the point
    deepest inside each template (:func:`~taichi_hsdem.geometry.distance.inside_point`,
    not its centroid, which a concave body may not contain), the one the "passed
    through" check tests; ``is_circle`` and ``radius`` for the templates that are
    exact circles."""
    ls_phi: Array
    ls_grad: Array
    ls_meta: Array
    ls_geo: Array
    node_pos: Array
    node_area: Array
    node_meta: Array
    inside: Array
    is_circle: Array
    radius: Array
    node_count: np.ndarray

    @classmethod
    def of(cls, model) -> "Templates":
        sp = model.species
        spacings = [None if model.all_disks else s.ls_spacing for s in sp]
        stk = levelset.stack([s.shape for s in sp], spacings)
        ls_phi = stk["ls_phi"] if stk["ls_phi"].size else np.zeros(1)
        ls_grad = np.zeros((ls_phi.size, 2))
        for off, (nx, ny), h in zip(stk["ls_offset"], stk["ls_shape"], stk["ls_spacing"]):
            if nx:
                ls_grad[off:off + nx * ny] = _grid_gradient(
                    ls_phi[off:off + nx * ny].reshape(nx, ny), h)
        return cls(ls_phi=array(ls_phi), ls_grad=array(ls_grad),
                   ls_meta=array(np.column_stack([stk["ls_offset"], stk["ls_shape"]]), ti.i32),
                   ls_geo=array(np.column_stack([stk["ls_origin"], stk["ls_spacing"]])),
                   node_pos=array(stk["node_pos"]),
                   node_area=array(np.concatenate([shp.boundary_vectors(s.shape.nodes)
                                                   for s in sp])),
                   node_meta=array(np.column_stack([stk["node_offset"], stk["node_count"]]),
                                   ti.i32),
                   inside=array(np.array([distance.inside_point(s.shape)[0] for s in sp])),
                   is_circle=array(stk["is_circle"], ti.i32), radius=array(stk["radius"]),
                   node_count=np.asarray(stk["node_count"]))


@bundle
class WallGrid(Bundle):
    """The walls' level set (positive in the fluid), flat x-first, with its
    gradient, its grid ``shape`` (nx, ny) and ``geo`` (origin x, origin y,
    spacing: ``layout.GEO_*``)."""
    phi: Array
    grad: Array
    shape: Array
    geo: Array

    @classmethod
    def of(cls, model) -> "WallGrid":
        wf = model.wall_field
        return cls(phi=array(wf.phi.ravel()), grad=array(_grid_gradient(wf.phi, wf.spacing)),
                   shape=array(np.array(wf.phi.shape), ti.i32),
                   geo=array(np.array([wf.origin[0], wf.origin[1], wf.spacing], dtype=float)))


class ShearHistory(Bundle):
    """Shear force of every contact, per body and surface node: ``slots`` partners
    per node (``partner + 1`` in the int array, 0 for a free slot; the walls are
    partner ``N``). Double-buffered: a step reads :attr:`old` and writes
    :attr:`new`, then :meth:`swap`; the pack holds them as ``partners_old``,
    ``shear_old``, ``partners_new``, ``shear_new``."""
    Pack = pack_type("ShearHistory", ("partners_old", "shear_old", "partners_new",
                                      "shear_new"))

    def __init__(self, R: int, N: int, nodes: int, slots: int):
        self.slots = slots
        shape = (R, N, nodes, slots)
        self.buffers = [(_zeros(shape, ti.i32), _zeros(shape, vector=True))
                        for _ in range(2)]

    @classmethod
    def of(cls, model, templates: Templates, R: int, N: int) -> "ShearHistory":
        if model.all_disks:   # node 1 of a disk: the rolling moments (``.x``)
            return cls(R, N, 2 if model.rolling else 1, DISK_HISTORY_SLOTS)
        return cls(R, N, int(templates.node_count.max()), LS_HISTORY_SLOTS)

    @property
    def old(self):
        return self.buffers[0]

    @property
    def new(self):
        return self.buffers[1]

    def arrays(self) -> dict:
        (partners_old, shear_old), (partners_new, shear_new) = self.old, self.new
        return dict(partners_old=partners_old, shear_old=shear_old,
                    partners_new=partners_new, shear_new=shear_new)

    def swap(self):
        self.buffers.reverse()

    def clear(self):
        for partners, _ in self.buffers:
            partners.fill(0)


def flags() -> object:
    """The batch-wide ``layout.F_*`` counters, zeroed."""
    return _zeros(layout.N_FLAGS, ti.i32)
