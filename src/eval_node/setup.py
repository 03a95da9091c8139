from setuptools import find_packages, setup

package_name = "eval_node"

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
    description=("MCAP bag recorder and offline evaluation of the pipeline by KITTI rules"),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "bag_recorder = eval_node.recorder:main",
            "evaluate = eval_node.cli:main",
        ],
    },
)
