"""DEM particle engine: contact laws, walls, neighbour search, integration (physics.md §1, §3).

Public API::

    from cfddem.particles import ParticleSystem, StepStatus, LinearContact, PlaneWall, RectangleWall
"""

from cfddem.particles.contact import LinearContact
from cfddem.particles.system import ParticleSystem, StepStatus
from cfddem.particles.walls import PlaneWall, RectangleWall, Wall

__all__ = ["LinearContact", "ParticleSystem", "StepStatus", "Wall", "PlaneWall", "RectangleWall"]
