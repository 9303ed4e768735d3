"""The shipped RViz2 config and Foxglove layout parse and show the right topics (they
cannot be opened here: no RViz2, no Foxglove); marker_node.yaml documents every
parameter the node declares.
"""
import json
import pathlib

import yaml

from vlc_view.marker_node import NODE_PARAMETERS

CONFIG = pathlib.Path(__file__).resolve().parents[1] / 'config'


def test_rviz_config_shows_the_marker_array_in_map():
    rviz = yaml.safe_load((CONFIG / 'vlc_view.rviz').read_text())
    manager = rviz['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == 'map'
    arrays = [d for d in manager['Displays'] if d['Class'] == 'rviz_default_plugins/MarkerArray']
    assert len(arrays) == 1 and arrays[0]['Enabled']
    assert arrays[0]['Topic']['Value'] == '/markers'
    assert arrays[0]['Topic']['Reliability Policy'] == 'Reliable'
    assert set(arrays[0]['Namespaces']) == {'lamps', 'lamp_labels', 'train',
                                            'along_track_3sigma', 'rays', 'track'}


def _panels(tree):
    if isinstance(tree, str):
        return [tree]
    return _panels(tree['first']) + _panels(tree['second'])


def test_foxglove_layout_has_the_3d_panel_plots_and_diagnostics():
    layout = json.loads((CONFIG / 'foxglove_layout.json').read_text())
    panels = layout['configById']
    assert sorted(_panels(layout['layout'])) == sorted(panels)
    three_d = [c for k, c in panels.items() if k.startswith('3D!')]
    assert len(three_d) == 1 and three_d[0]['topics']['/markers']['visible']
    assert three_d[0]['followTf'] == 'map'
    paths = [p['value'] for k, c in panels.items() if k.startswith('Plot!')
             for p in c['paths']]
    assert '/train/pose.pose.position.x' in paths
    assert any(p.startswith('/train/pose_with_covariance.pose.covariance') for p in paths)
    diag_plots = [p for p in paths if p.startswith('/diagnostics.status')]
    assert any('train_localizer: integrity' in p for p in diag_plots)
    summaries = [c for k, c in panels.items() if k.startswith('DiagnosticSummary!')]
    assert summaries and summaries[0]['topicToRender'] == '/diagnostics'


def test_marker_node_yaml_documents_every_parameter():
    params = yaml.safe_load((CONFIG / 'marker_node.yaml').read_text())['/**']['ros__parameters']
    declared = {name: default for name, default, _ in NODE_PARAMETERS}
    assert params == declared
    text = (CONFIG / 'marker_node.yaml').read_text()
    for name in declared:
        line = next(line for line in text.splitlines() if line.strip().startswith(name + ':'))
        assert '#' in line, name
