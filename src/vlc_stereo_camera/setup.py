from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_stereo_camera'

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
    description=('Synthetic tunnel rig: lamp world, train motion and vibration, rolling-shutter '
                 'stereo VLC renderer, ADIS16488 IMU model, ground truth.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'stereo_camera_node = vlc_stereo_camera.stereo_camera_node:main',
            'adis16488_node = vlc_stereo_camera.adis16488_node:main',
            'photodiode_node = vlc_stereo_camera.photodiode_node:main',
            'make_installation = vlc_stereo_camera.make_installation:main',
        ],
    },
)
