"""Global route and references: the tether-aware route, the reach proofs, the chain clearance, the RRT* leader path, the
time law and the per-robot references (sequential ones in ``train``).
"""
