"""Structured hexahedral spectral-element mesh of a rectangular plate.

The plate occupies [0, Lx] x [0, Ly] x [0, t]; z = t is the top surface the chain stands on, x = 0
the clamped edge the distance L is measured from, and the chain sits on the centre line y = Ly/2.
Each direction is cut into elements and each element carries the tensor product of GLL points of
its own order. The cut along x is graded so that x = L always falls on a GLL node of the mesh
(the contact point is a top-surface node for any L), with at most two element sizes per
direction, so the whole mesh has only a few distinct element shapes.

With ``symmetry`` only the half y <= Ly/2 is meshed; the plane y = Ly/2 is then a mirror plane.

The chain pushes on the plate through a contact patch: a smooth pressure bump of radius r_c
centred under the chain (:meth:`PlateMesh.contact_load`). Its consistent nodal forces also weigh
the top-surface deflection the Hertz spring sees, so load and deflection are work conjugate. A
single-node force (r_c = 0) is kept for comparison only: in 3D elasticity a point force has an
unbounded (~1/r) deflection under it, so the nodal deflection grows without limit as the mesh is
refined. With a patch, the grading may add fine elements around the chain
(:func:`refined_edges`) so the patch is resolved.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .gll import gll_points, lagrange_basis


def graded_edges(length: float, n_elements: int, target: float, order: int) -> np.ndarray:
    """Element boundaries on [0, length] with a GLL node of ``order`` exactly at ``target``.

    The first n1 elements have size h1, the other n - n1 size h2; ``target`` is GLL node s of
    element e < n1, i.e. target = (e + s) h1 with s a GLL fraction in (0, 1]. Among all such
    layouts the one with element sizes closest to the uniform size (in log ratio) wins, so the
    mesh stays as uniform as possible and the stable step is not spoilt by a sliver element.
    """
    if n_elements < 1:
        raise ValueError(f"need at least one element, got {n_elements}")
    if not 0.0 <= target <= length:
        raise ValueError(f"target {target} lies outside [0, {length}]")
    uniform = np.linspace(0.0, length, n_elements + 1)
    fractions = (gll_points(order)[1:] + 1.0) / 2.0  # node positions in an element, 0 excluded
    nodes = (uniform[:-1, None] + fractions[None, :] * (length / n_elements)).ravel()
    if target == 0.0 or np.min(np.abs(nodes - target)) <= 1e-12 * length:
        return uniform
    h_nom = length / n_elements
    best: tuple[float, np.ndarray] | None = None
    for n1 in range(1, n_elements + 1):
        for e in range(n1):
            for s in fractions:
                h1 = target / (e + s)
                rest = length - n1 * h1
                n2 = n_elements - n1
                if n2 == 0:
                    if abs(rest) > 1e-12 * length:
                        continue
                    sizes = [h1]
                elif rest <= 0.0:
                    continue
                else:
                    sizes = [h1, rest / n2]
                score = max(abs(np.log(h / h_nom)) for h in sizes)
                if best is None or score < best[0] - 1e-12:
                    edges = np.concatenate(
                        (np.arange(n1 + 1) * h1,
                         n1 * h1 + np.arange(1, n2 + 1) * (rest / max(n2, 1)))
                    )
                    edges[-1] = length
                    best = (score, edges)
    if best is None:  # one element and the target inside it at no GLL node
        raise ValueError(
            f"cannot place a node at {target} with {n_elements} element(s) of order {order}"
        )
    return best[1]


def _side(avail: float, fine: float, fine_extent: float, nominal: float) -> list[float]:
    """Element sizes outward from a point over a length ``avail``: fine near it, then doubling.

    Elements of size ``fine`` cover ``fine_extent``; sizes then double while below ``nominal``
    (never a jump above 2); the rest is cut into equal elements near ``nominal``. A remainder too
    short for an element of the current size is merged into the last one, so no element is
    smaller than ``fine`` (the smallest element sets the stable time step).
    """
    sizes: list[float] = []
    pos, size = 0.0, fine
    tol = 1e-12 * max(avail, nominal)
    while True:
        if pos >= fine_extent - tol and size < nominal / 1.5:
            size *= 2.0
        if pos >= fine_extent - tol and size >= nominal / 1.5:
            break
        if pos + size > avail + tol:
            break
        sizes.append(size)
        pos += size
    rest = avail - pos
    if rest > tol:
        n = max(1, round(rest / nominal))
        if rest / n >= (sizes[-1] if sizes else fine) * (1 - 1e-9) or not sizes:
            sizes.extend([rest / n] * n)
        else:
            sizes[-1] += rest
    return sizes


def refined_edges(length: float, n_elements: int, target: float, fine: float,
                  fine_extent: float) -> np.ndarray:
    """Element boundaries on [0, length] with elements of size ``fine`` around ``target``.

    ``target`` is an element boundary, with elements of size ``fine`` over ``fine_extent`` on
    each side, then sizes doubling up to about the nominal ``length / n_elements``. Near an end
    (closer than one fine element) the fine zone starts at that end instead, and ``target`` need
    not be a node: the contact patch is integrated with the shape functions wherever it lies.
    """
    nominal = length / n_elements
    if not 0.0 <= target <= length:
        raise ValueError(f"target {target} lies outside [0, {length}]")
    if fine >= nominal:
        return np.linspace(0.0, length, n_elements + 1)
    left, right = target, length - target
    if left < fine:  # start at x = 0; the fine zone reaches past the target
        sizes = _side(length, fine, target + fine_extent, nominal)
    elif right < fine:
        sizes = _side(length, fine, right + fine_extent, nominal)[::-1]
    else:
        sizes = _side(left, fine, fine_extent, nominal)[::-1] + \
            _side(right, fine, fine_extent, nominal)
    edges = np.concatenate(([0.0], np.cumsum(sizes)))
    edges[-1] = length
    return edges


def patch_pressure(r: np.ndarray, radius: float) -> np.ndarray:
    """Unnormalised contact pressure at distance r: (1 - r^2/r_c^2)^2 inside r_c, 0 outside.

    Smooth (C1) at the rim, so the patch load and the field under it converge at the rate of
    the elements rather than being limited by a pressure jump.
    """
    q = np.clip(1.0 - (r / radius) ** 2, 0.0, None)
    return q * q


def _node_coordinates(edges: np.ndarray, order: int) -> np.ndarray:
    """Global 1D node coordinates: GLL points of every element, shared endpoints once."""
    frac = (gll_points(order) + 1.0) / 2.0
    h = np.diff(edges)
    pts = edges[:-1, None] + h[:, None] * frac[None, :]
    coords = np.concatenate((pts[:, :-1].ravel(), [edges[-1]]))
    # snap element endpoints exactly
    coords[::order] = edges
    return coords


@dataclass(frozen=True)
class PlateMesh:
    """A structured spectral-element mesh of a plate (see the module docstring)."""

    x_edges: np.ndarray
    y_edges: np.ndarray
    z_edges: np.ndarray
    order: tuple[int, int, int]
    contact_xy: tuple[float, float]
    symmetry: bool = False
    full_width: float = field(default=0.0)
    contact_radius: float = 0.0

    # Node grid -------------------------------------------------------------------------------
    @cached_property
    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """1D node coordinates along x, y, z."""
        return (
            _node_coordinates(self.x_edges, self.order[0]),
            _node_coordinates(self.y_edges, self.order[1]),
            _node_coordinates(self.z_edges, self.order[2]),
        )

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """Nodes along (x, y, z)."""
        ax, ay, az = self.axes
        return ax.size, ay.size, az.size

    @property
    def elements(self) -> tuple[int, int, int]:
        """Element counts along (x, y, z)."""
        return len(self.x_edges) - 1, len(self.y_edges) - 1, len(self.z_edges) - 1

    @property
    def n_elements(self) -> int:
        ex, ey, ez = self.elements
        return ex * ey * ez

    @property
    def n_nodes(self) -> int:
        nx, ny, nz = self.grid_shape
        return nx * ny * nz

    @property
    def n_dofs(self) -> int:
        return 3 * self.n_nodes

    def node_index(
        self, i: np.ndarray | int, j: np.ndarray | int, k: np.ndarray | int
    ) -> np.ndarray:
        """Global node number of grid indices (i along x fastest, then j, then k)."""
        nx, ny, _ = self.grid_shape
        return (np.asarray(k) * ny + np.asarray(j)) * nx + np.asarray(i)

    @cached_property
    def nodes(self) -> np.ndarray:
        """(n_nodes, 3) node coordinates, m."""
        ax, ay, az = self.axes
        z, y, x = np.meshgrid(az, ay, ax, indexing="ij")
        return np.column_stack((x.ravel(), y.ravel(), z.ravel()))

    # Elements ---------------------------------------------------------------------------------
    @property
    def nodes_per_element(self) -> int:
        px, py, pz = self.order
        return (px + 1) * (py + 1) * (pz + 1)

    @cached_property
    def connectivity(self) -> np.ndarray:
        """(n_elements, nloc) global node numbers; local order has x fastest, then y, then z."""
        px, py, pz = self.order
        ex, ey, ez = self.elements
        a = np.arange(px + 1)
        b = np.arange(py + 1)
        c = np.arange(pz + 1)
        cc, bb, aa = np.meshgrid(c, b, a, indexing="ij")
        local = (aa.ravel(), bb.ravel(), cc.ravel())
        ek, ej, ei = np.meshgrid(np.arange(ez), np.arange(ey), np.arange(ex), indexing="ij")
        i = ei.ravel()[:, None] * px + local[0][None, :]
        j = ej.ravel()[:, None] * py + local[1][None, :]
        k = ek.ravel()[:, None] * pz + local[2][None, :]
        return self.node_index(i, j, k).astype(np.int64)

    @cached_property
    def element_sizes(self) -> np.ndarray:
        """(n_elements, 3) element edge lengths, same element order as ``connectivity``."""
        hz, hy, hx = np.meshgrid(
            np.diff(self.z_edges), np.diff(self.y_edges), np.diff(self.x_edges), indexing="ij"
        )
        return np.column_stack((hx.ravel(), hy.ravel(), hz.ravel()))

    @cached_property
    def shapes(self) -> tuple[np.ndarray, np.ndarray]:
        """(distinct element sizes (n_shapes, 3), shape id of each element)."""
        scale = float(np.max(self.element_sizes))
        keys = np.round(self.element_sizes / scale, 11)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        sizes = np.array([self.element_sizes[np.argmax(inverse == s)] for s in range(len(uniq))])
        return sizes, inverse.ravel().astype(np.int64)

    # Special nodes ----------------------------------------------------------------------------
    @cached_property
    def contact_node(self) -> int:
        """The top-surface node under the chain (x = L, y = Ly/2, z = t)."""
        ax, ay, az = self.axes
        i = int(np.argmin(np.abs(ax - self.contact_xy[0])))
        j = int(np.argmin(np.abs(ay - self.contact_xy[1])))
        tol = 1e-9 * max(ax[-1], ay[-1])
        if abs(ax[i] - self.contact_xy[0]) > tol or abs(ay[j] - self.contact_xy[1]) > tol:
            raise AssertionError("mesh grading failed to put a node under the chain")
        return int(self.node_index(i, j, az.size - 1))

    @property
    def share(self) -> float:
        """Part of the plate (and of the contact force) this mesh carries: 1/2 for a half model."""
        return 0.5 if self.symmetry else 1.0

    @cached_property
    def contact_load(self) -> tuple[np.ndarray, np.ndarray]:
        """(top-surface nodes, weights b) of the contact patch, sum(b) = :attr:`share`.

        b_a = integral over the top surface of N_a(x, y) p(x, y) dA for the normalised pressure
        bump p of radius r_c (:func:`patch_pressure`), integrated with Gauss-Legendre points over
        each element's part of the patch's bounding square, so the nodal forces are the consistent
        ones on any mesh, fine or coarse. A contact force F acts as the nodal forces F b, and the
        deflection under the chain is w = b . u_z / share (work conjugate: F w is the work). A
        patch cut by the plate edge or by the mirror plane is renormalised to the part on the
        (modelled) plate. r_c = 0: the single node under the chain, weight ``share``.
        """
        if self.contact_radius <= 0.0:
            return np.array([self.contact_node]), np.array([self.share])
        rc = self.contact_radius
        cx, cy = self.contact_xy
        ax, ay, az = self.axes
        px, py, _ = self.order
        gx, gw = np.polynomial.legendre.leggauss(24)
        weights: dict[int, float] = {}
        for ex in range(len(self.x_edges) - 1):
            x0 = max(self.x_edges[ex], cx - rc)
            x1 = min(self.x_edges[ex + 1], cx + rc)
            if x1 <= x0:
                continue
            for ey in range(len(self.y_edges) - 1):
                y0 = max(self.y_edges[ey], cy - rc)
                y1 = min(self.y_edges[ey + 1], cy + rc)
                if y1 <= y0:
                    continue
                xs = 0.5 * (x0 + x1) + 0.5 * (x1 - x0) * gx
                ys = 0.5 * (y0 + y1) + 0.5 * (y1 - y0) * gx
                wq = np.outer(gw, gw) * (0.25 * (x1 - x0) * (y1 - y0))  # [iy, ix]
                pres = patch_pressure(np.hypot(xs[None, :] - cx, ys[:, None] - cy), rc) * wq
                bx = lagrange_basis(ax[ex * px: ex * px + px + 1], xs)  # (q, a)
                by = lagrange_basis(ay[ey * py: ey * py + py + 1], ys)
                local = by.T @ pres @ bx  # (b_y, a_x)
                for jb in range(py + 1):
                    for ia in range(px + 1):
                        node = int(self.node_index(ex * px + ia, ey * py + jb, az.size - 1))
                        weights[node] = weights.get(node, 0.0) + float(local[jb, ia])
        nodes = np.array(sorted(weights), dtype=np.int64)
        b = np.array([weights[n] for n in nodes])
        keep = np.abs(b) > 1e-14 * np.abs(b).max()
        nodes, b = nodes[keep], b[keep]
        return nodes, b * (self.share / b.sum())

    def nearest_top_node(self, x: float, y: float) -> int:
        """Top-surface node closest to (x, y) (for probes)."""
        ax, ay, az = self.axes
        i = int(np.argmin(np.abs(ax - x)))
        j = int(np.argmin(np.abs(ay - y)))
        return int(self.node_index(i, j, az.size - 1))

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (elements, order, nodes, dofs, symmetry)."""
        return {
            "elements": list(self.elements),
            "order": list(self.order),
            "nodes": self.n_nodes,
            "dofs": self.n_dofs,
            "symmetry": self.symmetry,
            "element_shapes": len(self.shapes[0]),
            "min_element_m": [float(np.diff(e).min()) for e in
                              (self.x_edges, self.y_edges, self.z_edges)],
            "contact_radius_m": self.contact_radius,
            "contact_nodes": int(self.contact_load[0].size),
        }


def plate_mesh(
    size: tuple[float, float],
    thickness: float,
    elements: tuple[int, int, int] = (16, 16, 1),
    order: tuple[int, int, int] = (4, 4, 2),
    contact_x: float | None = None,
    symmetry: bool = False,
    contact_radius: float = 0.0,
    contact_refinement: float = 0,
) -> PlateMesh:
    """Mesh a plate of in-plane ``size`` (Lx, Ly) and ``thickness`` with the chain at x = contact_x.

    ``elements`` and ``order`` are per direction (x, y, z) for the full plate: the nominal
    (far-field) element counts. With ``symmetry`` the half y <= Ly/2 is meshed with ceil(ny / 2)
    nominal elements across. ``contact_radius`` r_c > 0 loads the plate through a patch
    (:meth:`PlateMesh.contact_load`); ``contact_refinement`` n > 0 then grades the in-plane mesh
    to elements of size 2 r_c / n within 2 r_c of the chain (doubling outward to the nominal
    size), so the patch is resolved however coarse the nominal mesh; n = 0 keeps the nominal
    mesh (the paper's layout, with a node under the chain).
    """
    lx, ly = float(size[0]), float(size[1])
    ex, ey, ez = (int(v) for v in elements)
    px, py, pz = (int(v) for v in order)
    if min(ex, ey, ez) < 1:
        raise ValueError(f"element counts must be >= 1, got {list(elements)}")
    if min(px, py, pz) < 1:
        raise ValueError(f"orders must be >= 1, got {list(order)}")
    rc = float(contact_radius)
    if rc < 0.0:
        raise ValueError(f"contact_radius must be >= 0, got {rc}")
    if contact_refinement < 0:
        raise ValueError(f"contact_refinement must be >= 0, got {contact_refinement}")
    cx = lx / 2.0 if contact_x is None else float(contact_x)
    if rc > 0.0 and contact_refinement > 0:
        fine, extent = 2.0 * rc / contact_refinement, 2.0 * rc
        x_edges = refined_edges(lx, ex, cx, fine, extent)
        if symmetry:
            half = refined_edges(ly, ey, ly / 2.0, fine, extent)
            y_edges = half[: int(np.argmin(np.abs(half - ly / 2.0))) + 1]
            y_edges[-1] = ly / 2.0
        else:
            y_edges = refined_edges(ly, ey, ly / 2.0, fine, extent)
    else:
        x_edges = graded_edges(lx, ex, cx, px)
        if symmetry:
            y_edges = np.linspace(0.0, ly / 2.0, -(-ey // 2) + 1)
        else:
            y_edges = graded_edges(ly, ey, ly / 2.0, py)
    z_edges = np.linspace(0.0, thickness, ez + 1)
    return PlateMesh(x_edges, y_edges, z_edges, (px, py, pz), (cx, ly / 2.0), symmetry, ly, rc)
