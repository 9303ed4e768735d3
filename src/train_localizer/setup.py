from glob import glob

from setuptools import find_packages, setup

package_name = 'train_localizer'

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
    description=('Stereo triangulation, Kalman fusion with the IMU along the track, integrity '
                 'checks; publishes the train position.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'train_localizer_node = train_localizer.train_localizer_node:main',
        ],
    },
)
