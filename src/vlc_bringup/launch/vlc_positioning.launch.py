"""The whole positioning graph: ``ros2 launch vlc_bringup vlc_positioning.launch.py``.

Starts the perception and localization nodes (decoder, spot locator, IMU compensator,
localizer) with their parameter files, and — unless ``use_rig:=false`` — the synthetic
rig (stereo camera and ADIS16488 on one scenario, ``config/rig.yaml``). With
``use_rig:=false`` the nodes wait for real sensors or a bag::

    ros2 launch vlc_bringup vlc_positioning.launch.py speed_kmh:=100.0
    ros2 launch vlc_bringup vlc_positioning.launch.py use_rig:=false use_sim_time:=true
    ros2 bag play bags/sample_100kmh --clock          # in a second shell

Arguments: ``use_rig`` (true), ``motion_profile`` (constant), ``speed_kmh`` (60.0),
``start_chainage_m`` (0.0), ``seed`` (1), ``alignment`` (straight; or e.g. curved_demo,
with its lamp map),
``lamp_map_path`` ('' = the alignment's), ``use_sim_time`` (false; true when replaying
a bag with ``--clock``), ``use_curvature`` (true: also start ``curvature_node``, whose
matches the localizer uses to re-acquire after a long lamp outage; on a straight line it
never publishes — set false there to save its CPU), ``curvature_speed_topic``
(``train/odometry``; a wheel tachometer's nav_msgs/Odometry if there is one),
``use_sbs_camera`` (false: true starts ``sbs_splitter_node`` on a side-by-side UVC camera's
``sbs_image_topic``, default ``image_raw``, split with ``sbs_calibration_files``, e.g.
``"[left.yaml,right.yaml]"``; ``sbs_input`` raw or compressed), ``use_view`` (false: true
starts ``marker_node``, the RViz2/Foxglove markers). Float arguments
need a decimal point. The same graph is started here, where the ``launch`` package is
not installable, by ``run_evaluation`` (``vlc_evaluation``), which runs the
installed executables as processes with the same parameter files.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue


def _config(package, name):
    return os.path.join(get_package_share_directory(package), 'config', name)


def generate_launch_description():
    use_rig = LaunchConfiguration('use_rig')
    use_curvature = LaunchConfiguration('use_curvature')
    sbs_input = LaunchConfiguration('sbs_input')
    sim_time = {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'),
                                               value_type=bool)}
    scenario = {
        'motion_profile': LaunchConfiguration('motion_profile'),
        'speed_kmh': ParameterValue(LaunchConfiguration('speed_kmh'), value_type=float),
        'start_chainage_m': ParameterValue(LaunchConfiguration('start_chainage_m'),
                                           value_type=float),
        'seed': ParameterValue(LaunchConfiguration('seed'), value_type=int),
        'alignment': LaunchConfiguration('alignment'),
    }
    lamp_map = {'lamp_map_path': LaunchConfiguration('lamp_map_path')}
    rig = _config('vlc_stereo_camera', 'rig.yaml')
    # one BLAS/OpenMP thread per node (scripts/env.sh says why), unless the caller chose
    threads = [SetEnvironmentVariable(name, os.environ.get(name, '1'))
               for name in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')]
    return LaunchDescription(threads + [
        DeclareLaunchArgument('use_rig', default_value='true',
                              description='Start the synthetic stereo camera and IMU.'),
        DeclareLaunchArgument('use_sim_time', default_value='false',
                              description='Follow /clock (bag replay with --clock).'),
        DeclareLaunchArgument('motion_profile', default_value='constant'),
        DeclareLaunchArgument('speed_kmh', default_value='60.0'),
        DeclareLaunchArgument('start_chainage_m', default_value='0.0'),
        DeclareLaunchArgument('seed', default_value='1'),
        DeclareLaunchArgument('lamp_map_path', default_value='',
                              description="Lamp map YAML ('' = the rig's map of the "
                                          'alignment; give it for a curved alignment, '
                                          'whose lamps are another line).'),
        DeclareLaunchArgument('alignment', default_value='straight',
                              description='Track alignment (straight, curved_demo, ...); '
                                          "the lamp map is the alignment's."),
        DeclareLaunchArgument('use_curvature', default_value='true',
                              description='Start curvature_node (re-acquisition aid after a '
                                          'long lamp outage; silent on a straight line).'),
        DeclareLaunchArgument('curvature_speed_topic', default_value='train/odometry',
                              description='nav_msgs/Odometry speed source of curvature_node '
                                          '(a wheel tachometer if available).'),
        DeclareLaunchArgument('use_sbs_camera', default_value='false',
                              description='Start sbs_splitter_node on a side-by-side stereo '
                                          'UVC camera (usb_cam, v4l2_camera).'),
        DeclareLaunchArgument('sbs_calibration_files', default_value='[]',
                              description='Its calibration: "[left.yaml,right.yaml]" '
                                          '(camera_info_manager) or OpenCV file(s).'),
        DeclareLaunchArgument('sbs_input', default_value='raw',
                              description="'raw' (sensor_msgs/Image) or 'compressed' (JPEG "
                                          'on <sbs_image_topic>/compressed).'),
        DeclareLaunchArgument('sbs_image_topic', default_value='image_raw',
                              description="The camera driver's side-by-side image topic."),
        DeclareLaunchArgument('use_view', default_value='false',
                              description='Start marker_node (RViz2/Foxglove markers).'),
        Node(package='vlc_camera_input', executable='sbs_splitter_node',
             parameters=[_config('vlc_camera_input', 'sbs_splitter_node.yaml'), sim_time,
                         {'input': sbs_input,
                          # (a launch argument is read as YAML: "[a.yaml,b.yaml]" a list)
                          'calibration_files': LaunchConfiguration('sbs_calibration_files')}],
             remappings=[('image_raw', LaunchConfiguration('sbs_image_topic')),
                         ('image_raw/compressed',
                          [LaunchConfiguration('sbs_image_topic'), '/compressed'])],
             condition=IfCondition(LaunchConfiguration('use_sbs_camera')), output='screen'),
        Node(package='vlc_view', executable='marker_node',
             parameters=[_config('vlc_view', 'marker_node.yaml'), sim_time, lamp_map],
             condition=IfCondition(LaunchConfiguration('use_view')), output='screen'),
        Node(package='vlc_stereo_camera', executable='stereo_camera_node',
             parameters=[rig, _config('vlc_stereo_camera', 'stereo_camera_node.yaml'),
                         scenario, lamp_map], condition=IfCondition(use_rig), output='screen'),
        Node(package='vlc_stereo_camera', executable='adis16488_node',
             parameters=[rig, _config('vlc_stereo_camera', 'adis16488_node.yaml'), scenario],
             condition=IfCondition(use_rig), output='screen'),
        Node(package='vlc_decoder', executable='vlc_decoder_node',
             parameters=[_config('vlc_decoder', 'vlc_decoder_node.yaml'), sim_time, lamp_map],
             output='screen'),
        Node(package='spot_locator', executable='spot_locator_node',
             parameters=[_config('spot_locator', 'spot_locator_node.yaml'), sim_time],
             output='screen'),
        Node(package='imu_compensator', executable='imu_compensator_node',
             parameters=[_config('imu_compensator', 'imu_compensator_node.yaml'), sim_time,
                         {'alignment': LaunchConfiguration('alignment')}],
             output='screen'),
        Node(package='train_localizer', executable='train_localizer_node',
             parameters=[_config('train_localizer', 'train_localizer_node.yaml'), sim_time,
                         lamp_map, {'alignment': LaunchConfiguration('alignment')}],
             output='screen'),
        Node(package='companion_localizers', executable='curvature_node',
             parameters=[_config('companion_localizers', 'curvature_node.yaml'), sim_time,
                         {'alignment': LaunchConfiguration('alignment'),
                          'odometry_topic': LaunchConfiguration('curvature_speed_topic')}],
             condition=IfCondition(use_curvature), output='screen'),
    ])
