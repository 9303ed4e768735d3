from glob import glob

from setuptools import find_packages, setup

package_name = 'companion_localizers'

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
    description='Companion train-positioning methods: VLC + RSSI trilateration, landmark + '
                'IMU dead reckoning, INS + stereo beacon ranging; bag scoring.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'rssi_localizer_node = companion_localizers.rssi_localizer_node:main',
            'dead_reckoning_node = companion_localizers.dead_reckoning_node:main',
            'ins_beacon_node = companion_localizers.ins_beacon_node:main',
            'curvature_node = companion_localizers.curvature_node:main',
        ],
    },
)
