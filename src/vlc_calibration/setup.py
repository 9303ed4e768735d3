from setuptools import find_packages, setup

package_name = 'vlc_calibration'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='VLC train positioning team',
    maintainer_email='dev@vlc-train-positioning.invalid',
    description=('Installation tools: stereo checkerboard calibration to camera_info YAML, '
                 'surveyed lamp lists (CSV) to the lamp map.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'stereo_calibrate = vlc_calibration.stereo_calibrate:main',
            'lamp_map_from_csv = vlc_calibration.lamp_map_from_csv:main',
        ],
    },
)
