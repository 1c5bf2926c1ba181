"""The world the chain moves in: the planar environment and its geometry queries, the map loaders, the scenarios (the
built-in ones in ``scenarios/``).
"""
