"""The elevation map's geometry: one definition of its size, cell, extent and cell centres.

Map cell ``(p, q)`` is centred at ``((p - (S-1)/2) * cell, (q - (S-1)/2) * cell)`` in the
sensor frame (metres); the map covers ``[-half_extent, half_extent]`` in x and y. The paper's
map is 121 x 121; at 0.25 m cells it is a 30.25 m square.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MAP_SIZE = 121  #: cells per side (the paper's image)
MAP_CELL = 0.25  #: metres per cell


@dataclass(frozen=True)
class MapGeometry:
    """``size x size`` cells of ``cell`` metres, centred on the sensor."""

    size: int = MAP_SIZE
    cell: float = MAP_CELL

    @property
    def extent(self) -> float:
        """Side length of the map in metres."""
        return self.size * self.cell

    @property
    def half_extent(self) -> float:
        """Half the side length: the map covers ``[-half_extent, half_extent]`` in x and y."""
        return 0.5 * self.size * self.cell

    def centres(self) -> np.ndarray:
        """``(size,)`` cell-centre coordinates along x (and y), metres."""
        return (np.arange(self.size) - 0.5 * (self.size - 1)) * self.cell
