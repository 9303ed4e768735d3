from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_camera_input'

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
    description=('Real camera input: a side-by-side stereo UVC camera split into the '
                 "graph's left and right mono8 images and camera_info."),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sbs_splitter_node = vlc_camera_input.sbs_splitter_node:main',
        ],
    },
)
