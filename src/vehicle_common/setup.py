from setuptools import find_packages, setup

package_name = "vehicle_common"

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
        "Shared pure code of the stereo tracking graph: KITTI formats, box geometry, frame "
        "conventions, orientation bins, message conversions, parameters and topic names"
    ),
    license="Apache-2.0",
)
