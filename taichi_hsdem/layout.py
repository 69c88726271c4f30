"""What the integers in the kernels' shared arrays mean: flag bits, counter slots,
table columns and capacities, in one place for the kernels and the host (plain
constants: the host imports this module without loading Taichi).

* ``Batch.bad[r]``: bits a kernel sets when realization ``r`` can no longer be
  trusted (the host stops it and reports why).
* ``flags[F_*]``: batch-wide counters and requests (int32).
* ``Materials.pair[a, b, PAIR_*]`` and ``Materials.wall[a, PAIR_*]``: the contact law
  of a species pair and of a species against the walls.
* ``geo[GEO_*]`` of a grid (``Templates.ls_geo[t]``, ``WallGrid.geo``,
  ``NeighborList.cell_geo``): its lower-left corner and spacing.
* ``SAMPLING``: how a surface node reads the pressure (``fluid.pressure_sampling``).
"""

# Batch.bad bits.
BAD_NAN = 1       # a non-finite position or velocity
BAD_FAST = 2      # a body moved more than a quarter of its size in one step
BAD_PASSED = 4    # a body's inside point ended up inside another body

# flags slots.
F_CELL_OVERFLOW = 0     # a cell of the cell list held more bodies than its capacity
F_HISTORY_OVERFLOW = 1  # contacts whose shear history had no free slot (counted)
F_REBUILD = 2           # some body moved half the Verlet skin: rebuild the lists
F_NBR_OVERFLOW = 3      # a body had more neighbours than the list's capacity
N_FLAGS = 4

# Columns of the contact-law tables (PAIR_MUR: rolling friction, disks only).
PAIR_KN, PAIR_KS, PAIR_MU, PAIR_CE, PAIR_MUR = 0, 1, 2, 3, 4
N_PAIR = 5

# Columns of a grid's geometry; the neighbour grid's holds the Verlet skin too.
GEO_OX, GEO_OY, GEO_H = 0, 1, 2
GEO_SKIN = 3

SAMPLING = {"bilinear": 0, "cell": 1}

# Contacts whose shear one surface node (level-set path) or one disk (analytic
# path) can remember at once; a contact beyond them keeps its force and loses its
# history (counted in flags[F_HISTORY_OVERFLOW]).
LS_HISTORY_SLOTS = 3
DISK_HISTORY_SLOTS = 8

# A level set's value outside its grid: far from the body, no contact.
OUTSIDE = 1.0e30
