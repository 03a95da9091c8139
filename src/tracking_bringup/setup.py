from glob import glob

from setuptools import find_packages, setup

package_name = "tracking_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
        ("share/" + package_name + "/config", glob("config/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perception team",
    maintainer_email="perception@example.com",
    description="Bring-up of the stereo vehicle tracking graph.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "stereo_tracking_launch = tracking_bringup.launcher:main",
            "stereo_tracking_demo = tracking_bringup.demo:main",
        ],
    },
)
