"""ament_python package: the ROS 2 node `node`, its managed (lifecycle) form `managed_node`, and the offline CLI
`triplet-normal`."""

import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.develop import develop
from setuptools.command.install import install

PACKAGE = "triplet_normal_ros"
#: Set (to anything) to leave the kernels for the first start to compile.
NO_WARM = "TRIPLET_NORMAL_NO_WARM"
#: A hang guard for the compilation (half a minute on a quiet 2-core machine), so a stuck one cannot stall the build.
WARM_TIMEOUT_S = 900


def warm_kernels(site: str) -> None:
    """Compile the CPU kernels into the numba cache of the copy of the package under `site`, in a fresh interpreter
    whose first path entry is `site` (so it imports that copy), so that the node's first start loads them in about a
    second instead of compiling them for half a minute (docs/CHOOSING.md, "The first start"). A failure is a warning:
    the package works without the cache, and its first start compiles the kernels."""
    if os.environ.get(NO_WARM):
        return
    print(f"{PACKAGE}: compiling the CPU kernels into the install (about half a minute; {NO_WARM}=1 skips it)")
    command = [sys.executable, "-m", f"{PACKAGE}.cli.main", "warm"]
    try:
        done = subprocess.run(command, cwd=site, capture_output=True, text=True, timeout=WARM_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        print(f"{PACKAGE}: warning: kernels not compiled ahead within {WARM_TIMEOUT_S} s, the first start will")
        return
    if done.returncode:
        lines = (done.stderr or done.stdout).strip().splitlines()
        print(f"{PACKAGE}: warning: kernels not compiled ahead, the first start will: {lines[-1] if lines else ''}")
    else:
        print(f"{PACKAGE}: {done.stdout.strip()}")


class InstallAndWarm(install):
    """`setup.py install` (what colcon build runs), then the kernels into the installed copy's cache. Not into a
    staging root (a wheel, a Debian package): the files move from there, perhaps to another CPU model."""

    def run(self) -> None:
        super().run()
        if not self.root:
            warm_kernels(self.install_lib)


class DevelopAndWarm(develop):
    """`setup.py develop` (colcon build --symlink-install), then the kernels into the source tree's cache."""

    def run(self) -> None:
        super().run()
        if not self.uninstall:
            warm_kernels(os.path.dirname(os.path.realpath(__file__)))


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
    cmdclass={"install": InstallAndWarm, "develop": DevelopAndWarm},
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
