"""FMI 3.0 array variables under the checks' scalar view.

The checks were written for FMI 2.0, where every variable is one value at one value reference.  An FMI 3.0
Float64 array ``X`` with n elements is one value reference holding n values, read and set whole.  Here each
element gets a name, ``X[k]`` (k = 1 … n in the array's serialization order, row-major), and a pseudo value
reference above every FMI 3 reference (which are 32-bit): the checks keep handling one value per reference,
and :class:`Elements` turns their calls back into whole-array FMI 3 calls (reading or setting the array, and
the directional derivatives with a seed on the one element).
"""

from __future__ import annotations

import numpy as np

#: pseudo value references of array elements start here (FMI 3 value references are below 2**32)
ELEMENT_BASE = 1 << 32


def size(v) -> int:
    """Number of values of an fmpy model variable (1 for a scalar)."""
    return int(np.prod(v.shape)) if getattr(v, "shape", None) else 1


class Elements:
    """The elements of an FMU's Float64 arrays: names, pseudo value references, and the calls on them."""

    def __init__(self, variables):
        self.sizes = {v.valueReference: size(v) for v in variables if v.type == "Float64" and size(v) > 1}
        self.table: list[tuple[int, int]] = []        # pseudo − ELEMENT_BASE → (array's reference, element index)
        self.names: dict[str, int] = {}               # element name → pseudo reference
        self.of: dict[str, list[str]] = {}            # array name → its element names
        for v in variables:
            if v.valueReference in self.sizes:
                self.of[v.name] = []
                for k in range(self.sizes[v.valueReference]):
                    name = f"{v.name}[{k + 1}]"
                    self.names[name] = ELEMENT_BASE + len(self.table)
                    self.of[v.name].append(name)
                    self.table.append((v.valueReference, k))

    def __bool__(self) -> bool:
        return bool(self.sizes)

    def scalar_names(self, names: list[str]) -> list[str]:
        """``names`` with each array replaced by its elements' names."""
        return [e for n in names for e in self.of.get(n, [n])]

    def _slots(self, refs) -> tuple[list[int], list[int], list[int | None]]:
        """The FMI 3 references to call for ``refs``, with where their values lie.

        Returns the references (each once, in first-seen order), their offsets in the values, and for each of
        ``refs`` the offset of its value (None: a whole array, at its reference's offset).
        """
        vrs: list[int] = []
        where: list[int | None] = []
        for r in map(int, refs):
            vr, k = self.table[r - ELEMENT_BASE] if r >= ELEMENT_BASE else (r, None)
            if vr not in vrs:
                vrs.append(vr)
            where.append(k)
        offsets = np.cumsum([0] + [self.sizes.get(vr, 1) for vr in vrs]).tolist()
        return vrs, offsets, where

    def _pick(self, refs, vrs, offsets, where, values) -> list:
        out: list = []
        for r, k in zip(map(int, refs), where, strict=True):
            vr = self.table[r - ELEMENT_BASE][0] if r >= ELEMENT_BASE else r
            o = offsets[vrs.index(vr)]
            out += values[o:o + self.sizes.get(vr, 1)] if k is None else [values[o + k]]
        return out

    def get(self, getter, refs) -> list:
        """fmi3GetFloat64 of elements, scalars and whole arrays."""
        vrs, offsets, where = self._slots(refs)
        return self._pick(refs, vrs, offsets, where, list(getter(vrs, nValues=offsets[-1])))

    def set(self, getter, setter, refs, values) -> None:
        """fmi3SetFloat64 of elements, scalars and whole arrays.

        An element is set with its array, whose other elements keep the values read just before.
        """
        vrs, offsets, where = self._slots(refs)
        arrays = [vr for vr in vrs if vr in self.sizes]
        full = np.zeros(offsets[-1])
        if arrays:
            current = getter(arrays, nValues=sum(self.sizes[vr] for vr in arrays))
            at = 0
            for vr in arrays:
                o = offsets[vrs.index(vr)]
                full[o:o + self.sizes[vr]] = current[at:at + self.sizes[vr]]
                at += self.sizes[vr]
        i = 0
        for r, k in zip(map(int, refs), where, strict=True):
            vr = self.table[r - ELEMENT_BASE][0] if r >= ELEMENT_BASE else r
            o, n = offsets[vrs.index(vr)], (1 if k is not None else self.sizes.get(vr, 1))
            full[o + (k or 0):o + (k or 0) + n] = values[i:i + n]
            i += n
        setter(vrs, list(full))

    def directional(self, derivative, unknowns, knowns, seed) -> list:
        """fmi3GetDirectionalDerivative with array elements among the unknowns and the knowns.

        The unknowns' whole arrays are asked for; the seed is zero on the knowns' arrays' other elements.
        """
        u_vrs, u_offsets, u_where = self._slots(unknowns)
        k_vrs, k_offsets, k_where = self._slots(knowns)
        full = np.zeros(k_offsets[-1])
        i = 0
        for r, k in zip(map(int, knowns), k_where, strict=True):
            vr = self.table[r - ELEMENT_BASE][0] if r >= ELEMENT_BASE else r
            o, n = k_offsets[k_vrs.index(vr)], (1 if k is not None else self.sizes.get(vr, 1))
            full[o + (k or 0):o + (k or 0) + n] += np.asarray(seed[i:i + n], float)
            i += n
        values = derivative(u_vrs, k_vrs, list(full), nSensitivity=u_offsets[-1])
        return self._pick(unknowns, u_vrs, u_offsets, u_where, list(values))
