from glob import glob

from setuptools import find_packages, setup

package_name = 'spot_locator'

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
    description=('Sub-pixel lamp spot centres in both stereo images (gray centroid, ellipse fit, '
                 'circularity fusion, Wiener deblurring).'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'spot_locator_node = spot_locator.spot_locator_node:main',
        ],
    },
)
