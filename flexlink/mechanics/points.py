"""The point rule's linear maps in the symbolic model: fields at the points, their running integrals, and back.

A second-order link's foreshortening is formed at material points (:class:`~flexlink.mechanics.shapes.base.
PointRule`: Gauss points on panels): the fields' values and slopes there, u = −½∫₀ˣ(v'² + w'²) as a running
integral, and Kane's sums taken back to the coordinates through the transposes of the same maps.  These maps
are constant, and how they are written decides most of the residual's operations on a link of many modes
(docs/performance.md): the dense modal maps stay calls (:func:`dense_map`); a panel's Gauss points lie in mirror
pairs about its middle, and the panel maps are written on the pairs' sums and differences, where a matrix odd or
even under the mirror needs half the products (:class:`MirrorMap`, :class:`PointShapes`).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.linalg

from flexlink.mechanics.shapes.base import PointRule, gauss_integration_matrix


class PointIntegration:
    """C = ``local + start·panel_sums``, the rule's ∫₀^{x_k}, and its transpose, as running sums over panels.

    A panel's Gauss points lie in mirror pairs about its middle (k and k' = n − 1 − k), and so does its
    integration matrix: S_{k'j'} = w_j − S_kj (∫ from the start to the mirror point is all but ∫ from the mirror
    to the end).  So S = A + ½·1wᵀ with A odd under the mirror, A_{k'j'} = −A_kj: A takes the pairs' sums
    f_j + f_j' to the odd part of its image and their differences to the even part, two (n/2)² blocks in place of
    one n² (:class:`MirrorMap`), and ½·1wᵀ f is half the panel's own Gauss sum, which the running sum over the
    panels forms anyway.  The same values as the dense panel blocks to rounding (tests/test_point_maps.py)
    in two thirds of their operations (2 040 against 3 000 for C and Cᵀ on 96 points): the 32-mode link's
    residual went from 15 700 to 13 800 operations.  A rule of an odd number of points a panel keeps the dense
    blocks.
    """

    def __init__(self, rule: PointRule):
        self.local, self.sums = (ca.sparsify(ca.DM(m)) for m in (rule.local, rule.panel_sums))
        self.panel = [int(k) for k in np.rint(rule.start.sum(axis=1))]     # the panel of each point
        self.panels = rule.panel_sums.shape[0]
        n = len(rule.x) // self.panels
        self.mirrored = n % 2 == 0 and n * self.panels == len(rule.x)
        if self.mirrored:
            half = 0.5 * rule.panel_sums.sum(axis=1)        # each panel's half length: Gauss weights sum to 2
            _, wt, S = gauss_integration_matrix(n)
            A = S - 0.5 * wt[None, :]
            try:
                self.forward, self.backward = MirrorMap(A, half), MirrorMap(A.T, half)
            except ValueError:          # not a Gauss rule's panels: the dense blocks
                self.mirrored = False
        if self.mirrored:
            pair_weights = np.kron(half, wt[: n // 2])       # w_j = w_j' of each pair
            self.pair_weights = ca.DM(pair_weights)
            self.gauss_sums = ca.sparsify(ca.DM(np.kron(np.eye(self.panels), np.ones((1, n // 2))) * pair_weights))
            self.pair_sums = ca.sparsify(ca.DM(np.kron(np.eye(self.panels), np.ones((1, n // 2)))))

    def __call__(self, f: ca.MX) -> ca.MX:
        """C f: this panel's part of ∫₀^{x_k} f, plus the Gauss sums of the panels before it."""
        if not self.mirrored:
            before = ca.vertcat(0, ca.cumsum(ca.mtimes(self.sums, f)))
            return ca.mtimes(self.local, f) + before[self.panel]
        even, odd = self.forward.split(f)
        own = ca.mtimes(self.gauss_sums, even)                   # each panel's Gauss sum
        offset = ca.cumsum(own) - 0.5 * own                      # the panels before, and half of its own
        return self.forward.join(even, odd, offset[self.forward.pairs.of_pair])

    def transpose(self, z: ca.MX) -> ca.MX:
        """Cᵀ z: each point takes its panel's ``localᵀ z`` and its Gauss weight times the z of later panels."""
        if not self.mirrored:
            per_panel = ca.vertcat(*[ca.sum1(z[[k for k, p in enumerate(self.panel) if p == q]])
                                     for q in range(self.panels)])
            total = ca.cumsum(per_panel)
            after = total[self.panels - 1] - total                   # Σ z over the panels after each panel
            return ca.mtimes(self.local.T, z) + ca.mtimes(self.sums.T, after)
        even, odd = self.backward.split(z)
        own = ca.mtimes(self.pair_sums, even)                    # Σ z over each panel
        total = ca.cumsum(own)
        after = total[self.panels - 1] - total + 0.5 * own       # the panels after, and half of its own
        return self.backward.join(even, odd, self.pair_weights * after[self.backward.pairs.of_pair])


class MirrorPairs:
    """The mirror pairs of a rule of P panels of n points (n even): point j of a panel and point n − 1 − j."""

    def __init__(self, panels: int, n: int):
        m = n // 2
        self.first = [p * n + j for p in range(panels) for j in range(m)]
        self.second = [p * n + n - 1 - j for p in range(panels) for j in range(m)]
        self.of_pair = [p for p in range(panels) for _ in range(m)]       # the panel of each pair
        order = np.empty(panels * n, dtype=int)
        order[self.first + self.second] = np.arange(panels * n)
        self.order = order.tolist()                   # the points' order from (first, second)

    def split(self, f: ca.MX) -> tuple[ca.MX, ca.MX]:
        """The pairs' sums and differences."""
        a, b = f[self.first], f[self.second]
        return a + b, a - b

    def join(self, first: ca.MX, second: ca.MX) -> ca.MX:
        """The points' vector from its values at the pairs' first and second points."""
        return ca.vertcat(first, second)[self.order]


class MirrorMap:
    """y = blockdiag(h_p M) f for a panel matrix M odd under the mirror (M_{k'j'} = −M_kj), through the pairs.

    With e_j = f_j + f_j', o_j = f_j − f_j' (j < n/2) and M's blocks α = M[j, j], β = M[j, j'] on the first half,
    y_k = X_k + Y_k and y_k' = Y_k − X_k with X = ½(α + β) e, Y = ½(α − β) o: 2·(n/2)² products a panel.
    """

    def __init__(self, M: np.ndarray, half: np.ndarray):
        n = M.shape[0]
        m, flip = n // 2, np.arange(n)[::-1]
        # odd exactly; in floating point to the rounding of S's inverse Vandermonde (5e-15 of |M| at 6 points,
        # 3e-14 at 8, 1e-12 at 12): the odd part is taken, after a check that allows that rounding
        if not np.allclose(M[np.ix_(flip, flip)], -M, rtol=0.0, atol=1e-10 * np.abs(M).max()):
            raise ValueError("the panel matrix is not odd under the mirror")
        M = 0.5 * (M - M[np.ix_(flip, flip)])
        first, second = np.arange(m), flip[:m]
        alpha, beta = M[np.ix_(first, first)], M[np.ix_(first, second)]
        self.X = ca.sparsify(ca.DM(np.kron(np.diag(half), 0.5 * (alpha + beta))))
        self.Y = ca.sparsify(ca.DM(np.kron(np.diag(half), 0.5 * (alpha - beta))))
        self.pairs = MirrorPairs(half.size, n)

    def split(self, f: ca.MX) -> tuple[ca.MX, ca.MX]:
        """The pairs' sums e and differences o."""
        return self.pairs.split(f)

    def join(self, even: ca.MX, odd: ca.MX, common: ca.MX) -> ca.MX:
        """The points' y, each pair's ``common`` added to both of its points."""
        Y = ca.mtimes(self.Y, odd) + common
        X = ca.mtimes(self.X, even)
        return self.pairs.join(Y + X, Y - X)


class PointShapes:
    """Values and slopes of a field at the rule's points, through the nodal values where the rule has them.

    Through the nodal values, a panel's points take their values from a few nodal coordinates (four for a
    Hermite element).  On the mirror pairs the panel's field is an even part, which gives the values' sums and
    the slopes' differences, and an odd part, which gives the values' differences and the slopes' sums; each
    part has as many coefficients as it has degrees of freedom (two for a cubic), formed once from the nodal
    values (:class:`_PanelParts`) and shared by values and slopes.  On the 32-mode link a field's values and
    slopes with one projection back take 2 100 operations against 3 290 through the nodal shapes' rows, and the
    residual went from 13 800 to 11 500 (tests/test_point_maps.py checks the maps against the Hermite cubics
    and the rule's φ and φ').
    """

    def __init__(self, rule: PointRule):
        self.factor, self.weights = rule.factor, rule.w
        self.parts: _PanelParts | None = None
        if rule.factor is not None:
            self.phi, self.slope = (ca.sparsify(ca.DM(m)) for m in (rule.factor.phi, rule.factor.slope))
            self.to_nodal, self.to_modal = dense_map(rule.factor.modal), dense_map(rule.factor.modal.T)
            self.parts = _PanelParts.of(rule)
        else:
            self.phi, self.slope = ca.sparsify(ca.DM(rule.phi)), ca.sparsify(ca.DM(rule.slope))

    def at_points(self, eta: ca.MX) -> tuple[ca.MX, ca.MX]:
        """(φ η, φ' η) at the points: N·n + 8 K operations through the nodal values, else 2 K·n."""
        nodal = self.to_nodal(eta) if self.factor is not None else eta
        if self.parts is not None:
            return self.parts.at_points(nodal)
        return ca.mtimes(self.phi, nodal), ca.mtimes(self.slope, nodal)

    def project(self, values: ca.MX, slopes: ca.MX) -> ca.MX:
        """φᵀ values + φ'ᵀ slopes, summed over the points (one transpose of the nodal map)."""
        if self.parts is not None:
            nodal = self.parts.project(values, slopes)
        else:
            nodal = ca.mtimes(self.phi.T, values) + ca.mtimes(self.slope.T, slopes)
        return self.to_modal(nodal) if self.factor is not None else nodal


class _PanelParts:
    """A rule's nodal shapes φ, φ' on the mirror pairs of its panels, as even and odd parts of few coefficients.

    On a panel of half length ℓ and centred coordinate τ ∈ [−1, 1], a nodal shape is a polynomial of degree
    below the panel's n points (a Hermite cubic): its monomial coefficients are read off its values at the
    points (V⁻¹ φ, V_kj = τ_k^j).  The even monomials give the values' pair sums and the slopes' pair
    differences, the odd ones the rest.  Each part's coefficient rows are W V with V in reduced echelon form
    (:func:`_reduced`), and c_e = V_e x, c_o = V_o x from the nodal values x (``T_e``, ``T_o``).  With A_e, A_o
    the even and odd monomials at the first points of the pairs times W, and B_e, B_o the slopes jτ^{j−1}/ℓ of
    the odd and even ones times W:

        values: first = A_e c_e + A_o c_o, second = A_e c_e − A_o c_o
        slopes: first = B_e c_o + B_o c_e, second = B_e c_o − B_o c_e

    and Kane's projection back is the transpose of the same.  A coefficient below 1e-8 of its shape's largest is
    the shapes' rounding (a Hermite cubic's are 0 or at least a quarter of the largest; the rule's φ carries
    1e-15, its φ' up to 1e-11 of a 5 mm element's); the parts must give the rule's φ and φ' back within 1e-9 of
    their magnitudes, or the rule keeps its sparse rows (None).
    """

    def __init__(self, pairs: MirrorPairs, T_e: ca.DM, T_o: ca.DM, A_e: ca.DM, A_o: ca.DM, B_e: ca.DM, B_o: ca.DM):
        self.pairs, self.T_e, self.T_o = pairs, T_e, T_o
        self.A_e, self.A_o, self.B_e, self.B_o = A_e, A_o, B_e, B_o

    @classmethod
    def of(cls, rule: PointRule) -> _PanelParts | None:
        """The parts of a rule with nodal values, or None where its panels are not mirror pairs of points."""
        assert rule.factor is not None
        panels = rule.panel_sums.shape[0]
        n = len(rule.x) // panels
        if n % 2 or n * panels != len(rule.x):
            return None
        pairs, m = MirrorPairs(panels, n), n // 2
        phi, slope = rule.factor.phi, rule.factor.slope
        parts: dict[str, list[np.ndarray]] = {name: [] for name in ("T_e", "T_o", "A_e", "A_o", "B_e", "B_o")}
        for p in range(panels):
            points = np.arange(p * n, (p + 1) * n)
            half = 0.5 * rule.panel_sums[p].sum()                       # Gauss weights sum to 2 on [−1, 1]
            tau = (rule.x[points] - rule.x[points].mean()) / half
            cols = np.flatnonzero(np.any(phi[points] != 0.0, axis=0) | np.any(slope[points] != 0.0, axis=0))
            T = np.linalg.solve(np.vander(tau, n, increasing=True), phi[np.ix_(points, cols)])
            T[np.abs(T) <= 1e-8 * np.abs(T).max(axis=0, initial=0.0)] = 0.0
            j = np.arange(n)
            monomials = np.vander(tau, n, increasing=True)
            rates = j[None, :] * tau[:, None] ** np.maximum(j - 1, 0)[None, :] / half
            values, slopes = np.zeros((n, len(cols))), np.zeros((n, len(cols)))
            for parity, kept in (("e", j % 2 == 0), ("o", j % 2 == 1)):
                used = kept & np.any(T != 0.0, axis=1)                  # the monomials some shape has
                W, V = _reduced(T[used])                                 # T[used] = W V
                rows = np.zeros((V.shape[0], phi.shape[1]))
                rows[:, cols] = V
                parts[f"T_{parity}"].append(rows)
                parts[f"A_{parity}"].append(monomials[:m][:, used] @ W)  # at the pairs' first points
                parts[f"B_{'o' if parity == 'e' else 'e'}"].append(rates[:m][:, used] @ W)
                values += monomials[:, used] @ W @ V
                slopes += rates[:, used] @ W @ V
            for got, want in ((values, phi[np.ix_(points, cols)]), (slopes, slope[np.ix_(points, cols)])):
                if not np.all(np.abs(got - want) <= 1e-9 * np.abs(want).max(initial=0.0)):
                    return None
        stacked = {name: ca.sparsify(ca.DM(np.vstack(blocks) if name.startswith("T") else _block_diagonal(blocks)))
                   for name, blocks in parts.items()}
        return cls(pairs, **stacked)

    def at_points(self, nodal: ca.MX) -> tuple[ca.MX, ca.MX]:
        """φ x and φ' x from the nodal values x."""
        c_e, c_o = ca.mtimes(self.T_e, nodal), ca.mtimes(self.T_o, nodal)
        even, odd = ca.mtimes(self.A_e, c_e), ca.mtimes(self.A_o, c_o)
        slope_even, slope_odd = ca.mtimes(self.B_e, c_o), ca.mtimes(self.B_o, c_e)
        return (self.pairs.join(even + odd, even - odd),
                self.pairs.join(slope_even + slope_odd, slope_even - slope_odd))

    def project(self, values: ca.MX, slopes: ca.MX) -> ca.MX:
        """φᵀ values + φ'ᵀ slopes, on the nodal values."""
        (ea, oa), (eb, ob) = self.pairs.split(values), self.pairs.split(slopes)
        c_e = ca.mtimes(self.A_e.T, ea) + ca.mtimes(self.B_o.T, ob)
        c_o = ca.mtimes(self.A_o.T, oa) + ca.mtimes(self.B_e.T, eb)
        return ca.mtimes(self.T_e.T, c_e) + ca.mtimes(self.T_o.T, c_o)


def _reduced(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W, V) with T = W V and V in reduced row echelon form: on its pivot columns the identity, so that those
    coefficients are nodal values themselves (no operation).  A Hermite element's even and odd coefficients
    are sums and differences of its nodal values: V's entries are then 0 and ±1, which the solve gives to
    rounding, and are set to them."""
    if T.shape[0] == 0:
        return np.zeros((0, 0)), np.zeros((0, T.shape[1]))
    scale = np.abs(T).max(axis=0)
    _, _, perm = scipy.linalg.qr(T / np.where(scale > 0.0, scale, 1.0), mode="economic", pivoting=True)
    pivots = np.sort(perm[:T.shape[0]])
    W = T[:, pivots]
    V = np.linalg.solve(W, T)
    whole = np.rint(V)
    snap = (np.abs(V - whole) <= 1e-12) & (np.abs(whole) <= 1.0)
    V[snap] = whole[snap]
    V[:, pivots] = np.eye(T.shape[0])
    return W, V


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    return scipy.linalg.block_diag(*blocks) if blocks else np.zeros((0, 0))


#: A constant map with at least this many entries stays a matrix product in the generated code.
DENSE_MAP_MIN_ENTRIES = 256
#: the names of those maps' CasADi functions begin so (flexlink.export.derivatives: the complex step carries them)
DENSE_MAP_PREFIX = "dense_map_"


def dense_map(matrix: np.ndarray):
    """``x ↦ matrix @ x`` for the symbolic model; a call that stays one in scalar code, for a large matrix.

    Where the matrix has DENSE_MAP_MIN_ENTRIES entries or more, the map is a CasADi function that expanding
    the model to scalar code keeps as a call (``never_inline``).

    The reduced FE link's modes in nodal coordinates are dense: as scalar code each entry is a constant, a
    product and a sum, three lines of C (the 32-mode link's four maps were 12 000 of its residual's 24 000
    operations); as a call, the generated code holds the matrix once as a constant array and multiplies in
    CasADi's dense loop.  Small maps stay scalar code, where they are cheapest.
    """
    m = ca.DM(matrix)
    if matrix.size < DENSE_MAP_MIN_ENTRIES:
        return lambda x: ca.mtimes(m, x)
    key = (matrix.shape, np.ascontiguousarray(matrix, dtype=float).tobytes())
    if key not in _DENSE_MAPS:      # one function a matrix: the generated code holds each matrix once
        x = ca.MX.sym("x", matrix.shape[1])
        _DENSE_MAPS[key] = ca.Function(f"{DENSE_MAP_PREFIX}{matrix.shape[0]}x{matrix.shape[1]}", [x],
                                       [ca.mtimes(m, x)], {"never_inline": True})
    return _DENSE_MAPS[key]


_DENSE_MAPS: dict[tuple, ca.Function] = {}
