from setuptools import find_packages, setup

package_name = "kitti_player_node"

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
    description=(
        "KITTI stereo player, synthetic KITTI-format sequence generator and MCAP bag replay"
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "kitti_player = kitti_player_node.node:main",
            "kitti_synth = kitti_player_node.synthetic:main",
            "bag_player = kitti_player_node.bag_player:main",
            "bag_recover = vehicle_common.bags.recovery:main",
        ],
    },
)
