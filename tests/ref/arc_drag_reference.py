#!/usr/bin/python3
"""Neo-Hookean static reference for the arc-drag beam of issue 11 (docs/physics.md section 9).

Beam 0.2 x 0.02 x 0.02 m as squish's box mesh (20 x 2 x 2 cells, the same Kuhn split into 6 tets
per cell as sq_mesh_box), clamped at x = 0 (all axes), E = 2 MPa, nu = 0.45, rho = 1000 kg/m^3,
gravity 9.81 m/s^2 along -z with lumped nodal masses (rho V / 4 per tet corner, as squish). The
9 nodes of the tip face x = 0.2 are translated (as squish's grab tool does) by the arc
displacement of the tip centre about the clamp centre line (the y axis through x = 0, z = 0.01):
(0.2 (cos t - 1), 0, 0.2 sin t) for t = 15, 45, 90 degrees, or by (0, 0, 0.1) (pull up 100 mm).

Material: compressible Neo-Hookean W = mu/2 (tr F^T F - 3) - mu ln J + lambda/2 (ln J)^2 with the
same Lame parameters (it agrees with linear elasticity at small strain), piecewise-constant F on
the same linear tets. Static equilibrium by load stepping (0.5 degree / 0.5 mm increments) and
Newton's method on the total energy with a backtracking line search (energy = +inf for J <= 0)
and a diagonal shift when the Hessian is not positive definite; converged to a residual of 1e-9
of the reaction scale.

Output (CSV on stdout, or --out FILE): case, volume ratio, tool force (the elastic force the body
exerts on the held nodes, summed: what squish's tool feedback reports at rest) fx, fy, fz, |F|.

Regenerate (Debian's python3-numpy and python3-scipy, installed by `make deps`):
    /usr/bin/python3 tests/ref/arc_drag_reference.py --out tests/ref/arc_drag.csv
Takes about 20 s here.
"""
import argparse
import math
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


def box_mesh(nx, ny, nz, size):
    """squish's sq_mesh_box: node (i, j, k) at index k*sz + j*sy + i; Kuhn split."""
    sx, sy, sz = 1, nx + 1, (nx + 1) * (ny + 1)
    x = np.zeros(((nx + 1) * (ny + 1) * (nz + 1), 3))
    for k in range(nz + 1):
        for j in range(ny + 1):
            for i in range(nx + 1):
                p = k * sz + j * sy + i
                x[p] = [size[0] if i == nx else size[0] * i / nx,
                        size[1] if j == ny else size[1] * j / ny,
                        size[2] if k == nz else size[2] * k / nz]
    perm = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    step = (sx, sy, sz)
    tets = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                base = k * sz + j * sy + i
                for p, pm in enumerate(perm):
                    v0 = base
                    v1 = v0 + step[pm[0]]
                    v2 = v1 + step[pm[1]]
                    v3 = v2 + step[pm[2]]
                    odd = p in (1, 2, 5)
                    tets.append((v0, v1, v3, v2) if odd else (v0, v1, v2, v3))
    return x, np.array(tets)


class NeoHookean:
    def __init__(self, x, tets, mu, lam, rho, g):
        self.X = x
        self.T = tets
        Dm = np.stack([x[tets[:, k]] - x[tets[:, 3]] for k in range(3)], axis=2)  # columns x_k - x_3
        self.V = -np.linalg.det(Dm) / 6  # (x0-x3, x1-x3, x2-x3) has the opposite orientation
        assert (self.V > 0).all()
        Dinv = np.linalg.inv(Dm)
        # gradients: F = sum_k x_k a_k^T, a_k = row k of Dm^-1 (k < 3), a_3 = -sum
        a = np.zeros((len(tets), 4, 3))
        a[:, :3, :] = Dinv
        a[:, 3, :] = -Dinv.sum(axis=1)
        self.a = a
        self.mu, self.lam = mu, lam
        n = len(x)
        self.mass = np.zeros(n)
        np.add.at(self.mass, tets.ravel(), np.repeat(rho * self.V / 4, 4))
        self.fext = np.outer(self.mass, g)  # gravity force per node
        rows, cols = [], []
        for p in range(4):
            for q in range(4):
                for i in range(3):
                    for k in range(3):
                        rows.append(3 * tets[:, p] + i)
                        cols.append(3 * tets[:, q] + k)
        self.hr = np.concatenate(rows)
        self.hc = np.concatenate(cols)

    def F(self, xc):
        return np.einsum('tpi,tpj->tij', xc[self.T], self.a)

    def energy(self, xc):
        F = self.F(xc)
        J = np.linalg.det(F)
        if (J <= 0).any():
            return math.inf
        lnJ = np.log(J)
        W = 0.5 * self.mu * (np.einsum('tij,tij->t', F, F) - 3) - self.mu * lnJ + 0.5 * self.lam * lnJ ** 2
        return float(np.dot(self.V, W) - np.sum(self.fext * (xc - self.X)))

    def internal(self, xc):
        """dE_el/dx per node (n x 3) and per tet quantities for the Hessian."""
        F = self.F(xc)
        J = np.linalg.det(F)
        G = np.linalg.inv(F)
        GT = np.transpose(G, (0, 2, 1))
        lnJ = np.log(J)
        P = self.mu * (F - GT) + self.lam * lnJ[:, None, None] * GT
        fe = np.einsum('t,tij,tpj->tpi', self.V, P, self.a)  # dE/dx_p
        g = np.zeros_like(xc)
        np.add.at(g, self.T.ravel(), fe.reshape(-1, 3))
        return g, F, G, lnJ

    def hessian(self, G, lnJ):
        mu, lam = self.mu, self.lam
        I3 = np.eye(3)
        # C[t, i, J, k, L] = dP_iJ / dF_kL
        C = (mu * np.einsum('ik,JL->iJkL', I3, I3)[None]
             + (mu - lam * lnJ)[:, None, None, None, None] * np.einsum('tJk,tLi->tiJkL', G, G)
             + lam * np.einsum('tJi,tLk->tiJkL', G, G))
        # H[t, p, i, q, k] = V sum_JL a_pJ C_iJkL a_qL
        H = np.einsum('t,tpJ,tiJkL,tqL->tpiqk', self.V, self.a, C, self.a)
        n3 = 3 * len(self.X)
        vals = np.concatenate([H[:, p, i, q, k] for p in range(4) for q in range(4)
                               for i in range(3) for k in range(3)])
        return sp.coo_matrix((vals, (self.hr, self.hc)), shape=(n3, n3)).tocsr()


def solve(model, xc, free, tol):
    """Newton on the free dofs from xc (modified in place); returns iterations."""
    fd = np.flatnonzero(free.ravel())
    for it in range(200):
        g, F, G, lnJ = model.internal(xc)
        r = (g - model.fext).ravel()[fd]
        rn = np.linalg.norm(r)
        if rn < tol:
            return it
        H = model.hessian(G, lnJ)[fd][:, fd]
        shift = 0.0
        diag = H.diagonal().mean()
        E0 = model.energy(xc)
        while True:
            Hs = H + shift * diag * sp.identity(len(fd), format='csr') if shift else H
            try:
                dx = -spla.spsolve(Hs.tocsc(), r)
            except Exception:
                dx = None
            if dx is not None and np.all(np.isfinite(dx)) and np.dot(dx, r) < 0:
                break
            shift = 1e-4 if shift == 0 else shift * 10
            if shift > 1e4:
                dx = -r / diag
                break
        step = 1.0
        flat = xc.ravel()
        base = flat[fd].copy()
        while step > 1e-12:
            flat[fd] = base + step * dx
            E1 = model.energy(xc)
            if E1 <= E0 + 1e-4 * step * np.dot(dx, r) or (rn < 1e3 * tol and E1 < math.inf):
                break
            step *= 0.5
        else:
            flat[fd] = base
            raise RuntimeError('line search failed (residual %g)' % rn)
    raise RuntimeError('Newton did not converge (residual %g)' % rn)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--cells', default='20,2,2')
    ap.add_argument('--out')
    args = ap.parse_args()
    nx, ny, nz = (int(s) for s in args.cells.split(','))
    L, W = 0.2, 0.02
    x, tets = box_mesh(nx, ny, nz, (L, W, W))
    E, nu, rho = 2e6, 0.45, 1000.0
    mu = E / (2 * (1 + nu))
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    model = NeoHookean(x, tets, mu, lam, rho, np.array([0, 0, -9.81]))
    clamp = x[:, 0] <= 1e-9
    tip = np.abs(x[:, 0] - L) <= 1e-9
    free = np.repeat((~clamp & ~tip)[:, None], 3, axis=1)
    tol = 1e-9 * mu * W * W
    out = open(args.out, 'w') if args.out else sys.stdout
    out.write('# Neo-Hookean static reference, tests/ref/arc_drag_reference.py --cells %s\n' % args.cells)
    out.write('case,volume_ratio,fx_N,fy_N,fz_N,force_N\n')
    vol0 = model.V.sum()

    def report(name, xc):
        g = model.internal(xc)[0]
        f = -g[tip].sum(axis=0)  # elastic force of the body on the held nodes
        J = np.linalg.det(model.F(xc))
        out.write('%s,%.6f,%.6g,%.6g,%.6g,%.6g\n' % (name, np.dot(model.V, J) / vol0, f[0], f[1], f[2],
                                                    np.linalg.norm(f)))
        out.flush()

    # arc: 0.5 degree increments, report at 15, 45, 90
    xc = x.copy()
    for s in range(1, 181):
        th = math.radians(0.5 * s)
        xc[tip] = x[tip] + np.array([L * (math.cos(th) - 1), 0, L * math.sin(th)])
        solve(model, xc, free, tol)
        if s in (30, 90, 180):
            report('arc %d deg' % (s // 2), xc)
    xc = x.copy()
    for s in range(1, 201):
        xc[tip] = x[tip] + np.array([0, 0, 0.0005 * s])
        solve(model, xc, free, tol)
    report('pull up 100 mm', xc)


if __name__ == '__main__':
    main()
