"""The bottom layer: what every other part may use and nothing in it imports the rest.

- ``atomic``: files written whole or not at all
- ``torchfile``: torch files saved atomically and loaded with ``weights_only=True``
- ``paths``: output names that cannot escape their folder
- ``checks``: argument checks whose error names the parameter
- ``geometry``: the elevation map's size, cell and cell centres (one source for both)
- ``structs``: nested config dataclasses built from plain or Hydra mappings
- ``version``: the package version
"""
