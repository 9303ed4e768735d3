
from glob import glob

from setuptools import find_packages, setup

package_name = 'vlc_evaluation'

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
    description=('Evaluation of the VLC positioning graph against ground truth: graph runner, '
                 'paper protocols, scoring, report, ablations, companion scenarios, benchmarks, '
                 'doc writers, offline replays.'),
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'run_evaluation = vlc_evaluation.cli:main',
            'localizer_replay = vlc_evaluation.localizer_replay:main',
            'lockstep_graph = vlc_evaluation.lockstep:main',
            'rig_benchmark = vlc_evaluation.benchmarks.rig:main',
            'decoder_benchmark = vlc_evaluation.benchmarks.decoder:main',
            'spot_benchmark = vlc_evaluation.benchmarks.spot_locator:main',
            'compensation_benchmark = vlc_evaluation.benchmarks.compensation:main',
            'localizer_benchmark = vlc_evaluation.benchmarks.localizer:main',
            'companion_benchmark = vlc_evaluation.benchmarks.companions:main',
            'curvature_benchmark = vlc_evaluation.benchmarks.curvature:main',
            'reacquisition_benchmark = vlc_evaluation.benchmarks.reacquisition:main',
            'two_host_benchmark = vlc_evaluation.benchmarks.two_hosts:main',
            'receivers_benchmark = vlc_evaluation.benchmarks.receivers:main',
            'companion_score = vlc_evaluation.companion_scoring:main',
            'render_demo_images = vlc_evaluation.demo_images:main',
            'sample_bag = vlc_evaluation.sample_bag:main',
            'sbs_bag = vlc_evaluation.sbs_bag:main',
            'fault_injector_node = vlc_evaluation.fault_injector_node:main',
            'calibrate_installation = vlc_evaluation.installation_calibration:main',
        ],
    },
)
