"""The physics of demcal: rigid multi-sphere bodies from meshes, the contact law, walls and
scenarios such as the vibration feeder.

Imports only numpy, numba, trimesh and pydantic; nothing of demcal's other packages.
"""
