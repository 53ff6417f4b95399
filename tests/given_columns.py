"""A ColumnCache whose base columns are given (no regressor, no filter) and whose effect columns
are the effects' own ``columns(data)``: the block bookkeeping is ColumnCache's, the columns the
test's. Shared by the selection tests."""

import numpy as np

from robust_drake.identification.fitting import ColumnCache


class GivenColumns(ColumnCache):
    def __init__(self, data, cols, names=("fc1", "fv1")):
        self.data = self.source = data
        self.exclude = self.keep = None
        self.base, self.base_names, self.n_rigid = np.ascontiguousarray(cols, float), list(names), 0
        self._effects, self._grams, self._lefts = {}, {}, {}
        self._last_prediction = (None, None)

    def effect(self, effect):
        key = self._key(effect)
        if key not in self._effects:
            c, nm = effect.columns(self.data)
            self._effects[key] = (np.ascontiguousarray(c, float), list(nm), effect)
        return self._effects[key][:2]
