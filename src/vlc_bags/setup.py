from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_bags'

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
    description=('rosbag2 recorder and player without the ros2 CLI, built on the rosbags library, '
                 'with a split writer that survives SIGKILL.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bag_recorder = vlc_bags.recorder_node:main',
            'bag_player = vlc_bags.player_node:main',
            'bench_recorder = vlc_bags.bench_recorder:main',
        ],
    },
)
