from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='VLC train positioning team',
    maintainer_email='dev@vlc-train-positioning.invalid',
    description=('Launch file of the whole VLC positioning graph: the synthetic rig (or a bag) and'
                 ' the processing nodes.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
        ],
    },
)
