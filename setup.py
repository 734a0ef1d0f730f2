"""ament_python package: the ROS 2 node `node`, its managed (lifecycle) form `managed_node`, and the offline CLI
`triplet-normal`."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "triplet_normal_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["checkpoints/*.safetensors", "sample_data/*.npz", "sample_data/*.md", "evaluation/*.cpp"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.xml"))),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    python_requires=">=3.10",  # the lowest the code needs: `make lint` checks it with vermin
    install_requires=["setuptools", "numpy", "scipy", "numba", "torch", "tqdm"],
    extras_require={
        "test": ["pytest", "hypothesis", "safetensors"],
        "train": ["trimesh", "manifold3d", "rtree", "tqdm", "matplotlib"],
        "io": ["pypcd4", "rosbags", "pyyaml"],
        "cluster": ["ray"],
    },
    zip_safe=False,
    maintainer="triplet_normal_ros maintainers",
    maintainer_email="maintainers@triplet-normal-ros.invalid",
    description="Learned (triplet) and PCA surface normals for sensor_msgs/PointCloud2.",
    license="BSD-3-Clause",
    entry_points={
        "console_scripts": [
            f"node = {PACKAGE}.ros.entry:node",
            f"managed_node = {PACKAGE}.ros.entry:managed_node",
            f"triplet-normal = {PACKAGE}.cli.main:main",
        ],
    },
)
