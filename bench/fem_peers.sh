#!/usr/bin/env bash
# Hinge FEM peers in one run: cellinject and scikit-fem on the same 2-D mesh.
#
# For circular notches with t/R = 0.05, 0.5 and 1 (R = 2 mm, width 5 mm, X2CrNi18-9,
# plane stress), `cellinject hinge --method fem --export-mesh` writes its finest mesh
# (9-node quadrilaterals following the notch, level 4) with its own stiffness and solve
# time. scikit-fem rebuilds exactly that mesh (MeshQuad2: the same corner, mid-edge and
# centre nodes), assembles plane-stress elasticity with the same 3x3 Gauss rule, clamps
# the left face, loads the right face with the same linear traction (unit moment),
# solves with SciPy's sparse direct solver and measures the rotation between the notch's
# end sections the same way (least-squares slope of the axial displacements).
# Printed per case: both stiffnesses, their relative difference, both solve times
# (assembly + solve, mesh building and file IO excluded) and their ratio.
#
# scikit-fem is installed from PyPI into target/fem-peers-venv on the first run.
# Usage: bash bench/fem_peers.sh
set -euo pipefail
cd "$(dirname "$0")/.."
work=target/fem-peers
venv=target/fem-peers-venv
mkdir -p "$work"
cargo build --release --quiet
bin=target/release/cellinject
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --upgrade pip
  "$venv/bin/pip" install --quiet scikit-fem scipy numpy
fi
printf '%-6s %9s %14s %14s %10s %12s %12s %7s\n' 't/R' unknowns k_cellinject k_skfem rel_diff t_cellinject t_skfem ratio
for tr in 0.05 0.5 1.0; do
  t=$(python3 -c "print($tr * 2e-3)")
  mesh="$work/hinge_$tr.json"
  "$bin" hinge --profile circular --thickness "$t" --radius 2e-3 --width 5e-3 \
    --method fem --plane stress --export-mesh "$mesh" >/dev/null
  "$venv/bin/python" - "$mesh" "$tr" <<'PY'
import json, sys, time
import numpy as np
from skfem import MeshQuad1, MeshQuad2, ElementQuad2, ElementVector, Basis, FacetBasis
from skfem import BilinearForm, LinearForm, asm, condense, solve
from skfem.helpers import ddot, sym_grad, trace, eye

d = json.load(open(sys.argv[1]))
xy = np.array(d["coords"]).T                      # 2 x N, our node ids
els = np.array(d["elements"])                      # E x 9, x fastest then y
cols = d["cols"]
# Corner (vertex) nodes, counter-clockwise per element.
corners = els[:, [0, 2, 8, 6]]
vid = np.unique(corners)
vmap = {n: k for k, n in enumerate(vid)}
t = np.vectorize(vmap.get)(corners).T
m1 = MeshQuad1(np.ascontiguousarray(xy[:, vid]), np.ascontiguousarray(t))
# Quadratic geometry: vertices, then one node per facet (our mid-edge node), then
# one per element (our centre node), in scikit-fem's dof order.
mid = {}
for e in els:
    for a, b, c in ((0, 2, 1), (2, 8, 5), (8, 6, 7), (6, 0, 3)):
        mid[frozenset((vmap[e[a]], vmap[e[b]]))] = e[c]
facet_nodes = np.array([mid[frozenset(f)] for f in m1.facets.T])
doflocs = np.hstack([xy[:, vid], xy[:, facet_nodes], xy[:, els[:, 4]]])
mesh = MeshQuad2(np.ascontiguousarray(doflocs), np.ascontiguousarray(t))

E, nu, b, M = d["youngs"], d["poisson"], d["width"], d["moment"]
lam = E * nu / (1 - nu**2)                         # plane stress
mu = E / (2 * (1 + nu))

start = time.perf_counter()
e = ElementVector(ElementQuad2())
basis = Basis(mesh, e, intorder=5)                 # 3x3 Gauss, as cellinject

@BilinearForm
def elasticity(u, v, w):
    eps_u, eps_v = sym_grad(u), sym_grad(v)
    sig = 2 * mu * eps_u + lam * eye(trace(eps_u), 2)
    return b * ddot(sig, eps_v)

K = asm(elasticity, basis)
xmax = doflocs[0].max()
xmin = doflocs[0].min()
right = mesh.facets_satisfying(lambda x: np.isclose(x[0], xmax))
fb = FacetBasis(mesh, e, facets=right, intorder=5)
h = np.ptp(xy[1][np.isclose(xy[0], xmax)])          # the right face's height
inertia = b * h**3 / 12

@LinearForm
def moment(v, w):
    return b * (-M * w.x[1] / inertia) * v[0]

f = asm(moment, fb)
D = basis.get_dofs(lambda x: np.isclose(x[0], xmin)).all()
u = solve(*condense(K, f, D=D))
elapsed = time.perf_counter() - start

# x-displacement dofs at our nodes.
ux = np.full(xy.shape[1], np.nan)
ux[vid] = u[basis.nodal_dofs[0]]
ux[facet_nodes] = u[basis.facet_dofs[0]]
ux[els[:, 4]] = u[basis.interior_dofs[0]]
def slope(col):
    ids = np.arange(d["rows"]) * cols + col
    yy, uu = xy[1, ids], ux[ids]
    return -np.polyfit(yy, uu, 1)[0]
a, c = d["section_columns"]
k = M / (slope(c) - slope(a))
kc = d["k_bend"]
print(f"{sys.argv[2]:<6} {d['unknowns']:9d} {kc:14.6f} {k:14.6f} {abs(k - kc) / kc:10.2e} "
      f"{d['solve_seconds']:11.4f}s {elapsed:11.4f}s {elapsed / d['solve_seconds']:7.1f}")
PY
done
