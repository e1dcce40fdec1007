"""Damage assessment on demand: cracks (features → unsupervised detector → instances with length and width)
and story drift/tilt (slab planes). `assess_damage` runs both on a map for `aftershock run --damage`."""

from aftershock.pipeline.damage.report import CrackResult, DamageReport, assess_damage, find_cracks

__all__ = ["CrackResult", "DamageReport", "assess_damage", "find_cracks"]
