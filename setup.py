"""ament_python package ``twinslam`` (``colcon build`` on ROS 2 hosts, ``pip install -e .``)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "twinslam"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["tests", "tests.*", "bench", "bench.*"]),
    package_data={"msg_schemas": ["msg/*.msg"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*_launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")
         + glob("config/*.json")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="twinslam developers",
    description="Edge-assisted device pose tracking for mobile AR over ROS 2 / DDS",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "sequence_player = twinslam.sequence_player.node:main",
            "device_tracker = device_tracker.node:main",
            "edge_mapper = edge_mapper.node:main",
            "udt_node = udt_node.node:main",
            "twinslam = twinslam.cli.main:main",
        ],
    },
)
