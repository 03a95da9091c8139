from setuptools import find_packages, setup

package_name = "tracker_node"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perception team",
    maintainer_email="perception@example.com",
    description=("3D multi-vehicle tracking (Kalman, particle, unfiltered) with data association"),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "vehicle_tracker = tracker_node.node:main",
            "tracker_offline = tracker_node.offline:main",
        ],
    },
)
