from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_view'

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
    description=('A view of the positioning: lamps, train and its along-track 3-sigma, the '
                 "last fix's rays as RViz2/Foxglove markers, and pictures of a bag."),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'marker_node = vlc_view.marker_node:main',
            'view_picture = vlc_view.picture:main',
        ],
    },
)
