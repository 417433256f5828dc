"""The paper's tables as package data (Yan & Regueiro, Computational Particle Mechanics 2019:
Tables 1, 3, 4 and 5, see README.md in this folder), so that a clone draws the paper's overlays
without the paper."""
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def table_path(name):
    """The path of the paper's table `name` (e.g. "table1_thread_schemes.csv") in the package."""
    return os.path.join(HERE, name)
