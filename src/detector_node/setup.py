from glob import glob

from setuptools import find_packages, setup

package_name = "detector_node"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/models", glob("models/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perception team",
    maintainer_email="perception@example.com",
    description=(
        "YOLOv2-style vehicle detector with 4-bin orientation (PyTorch), its training CLI and node"
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "vehicle_detector = detector_node.node:main",
            "detector_train = detector_node.train:main",
            "detector_anchors = detector_node.anchors:main",
            "detector_offline = detector_node.offline:main",
        ],
    },
)
