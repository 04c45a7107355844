"""DEM particle engine: contact laws, walls, neighbour search, integration (physics.md §1, §3).

Public API::

    from cfddem.particles import (ParticleSystem, StepStatus, LinearContact, HertzMindlinContact,
                                  PlaneWall, RectangleWall, CylinderWall, MeshWall)
"""

from cfddem.particles.contact import HertzMindlinContact, LinearContact
from cfddem.particles.mesh import MeshWall
from cfddem.particles.system import ParticleSystem, StepStatus
from cfddem.particles.walls import CylinderWall, PlaneWall, RectangleWall, Wall

__all__ = ["LinearContact", "HertzMindlinContact", "CylinderWall", "MeshWall", "ParticleSystem", "StepStatus", "Wall", "PlaneWall", "RectangleWall"]
