from setuptools import find_packages, setup

package_name = "stereo_depth_node"

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
    description=("SGBM + WLS disparity, point cloud and 3D ranging of 2D vehicle detections"),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "stereo_depth = stereo_depth_node.node:main",
            "stereo_offline = stereo_depth_node.offline:main",
        ],
    },
)
