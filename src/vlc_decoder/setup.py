from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_decoder'

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
    description=('VLC stripe decoder: lamp spots to CRC-checked UIDs and lamp-map positions, '
                 'tracked over frames.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'vlc_decoder_node = vlc_decoder.vlc_decoder_node:main',
        ],
    },
)
