"""Learned (triplet) and PCA surface normals for point clouds; the core imports no rclpy."""

__version__ = "0.1.0"
