from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='VLC train positioning team',
    maintainer_email='dev@vlc-train-positioning.invalid',
    description=('Foundation of the VLC positioning graph: lamp map, VLC protocol and CRC, camera '
                 'model, rotations, optical channel, records, ROS process conventions, parameters,'
                 ' point clouds, polled subscriptions, throttled warnings.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
    },
)
