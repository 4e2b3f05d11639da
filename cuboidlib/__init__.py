"""cuboidlib: the tested support library of the cuboid-abstraction course.

It implements Yang & Chen, "Unsupervised Learning for Cuboid Shape Abstraction via Joint
Segmentation from Point Clouds" (SIGGRAPH 2021). Each module is named after a concept of the paper;
see README.md for the map from the paper's sections and equations to modules.
"""

__version__ = "0.1.0"
