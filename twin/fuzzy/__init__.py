"""Fuzzy engine: IT2 and type-1 sets, Mamdani inference, type reduction."""
from twin.fuzzy.mamdani import MamdaniFLS
from twin.fuzzy.sets import IT2Set, Partition, Triangle, uniform_partition

__all__ = ["IT2Set", "MamdaniFLS", "Partition", "Triangle", "uniform_partition"]
