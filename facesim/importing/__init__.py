"""A simulation-ready face from a user's own meshes (``facesim model import``, issue 16).

meshes.py reads surfaces and volumes in any format trimesh or meshio reads, repairs what a
well-kept library can repair, splits volume cells into conforming tets, infers the units and
checks the anatomy; frame.py finds the anatomical frame (x left, y up, z forward, origin between
the condyles); landmarks.py finds, reads and writes the landmarks and the TMJ geometry.
"""
