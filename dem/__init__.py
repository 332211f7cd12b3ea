"""The physics of demcal: rigid bodies from meshes (sphere clumps, rounded polyhedra), the contact
law, walls, the built-in engine, scenarios such as the vibration feeder, and the engines that run
them.

Imports only numpy, numba, trimesh and pydantic; nothing of demcal's other packages.
"""
