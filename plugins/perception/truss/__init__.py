"""Truss environment modelling (paper 003): cylinder members completed by sliding bounding boxes.

``TrussPerception`` is the perception plugin (entry point ``truss``); ``TrussModeller`` is the
pure algorithm from a dense cloud to members, usable on its own.
"""

from climbd.plugins.perception.truss.model import TrussConfig, TrussModel, TrussModeller
from climbd.plugins.perception.truss.plugin import TrussPerception

__all__ = ["TrussConfig", "TrussModel", "TrussModeller", "TrussPerception"]
