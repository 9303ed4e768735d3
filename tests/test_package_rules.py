"""The package layering holds, every package.xml declares what its code, tests and launch
files use, and the drawing of the package graph in docs/ARCHITECTURE.md is the code's.
"""
import importlib.util
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location('package_graph',
                                               ROOT / 'scripts' / 'package_graph.py')
graph = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(graph)


def test_every_package_is_placed_and_no_arrow_runs_upward_or_across():
    assert graph.violations() == []


def test_receivers_never_import_the_simulator():
    uses = graph.imports()
    receivers = [p for p, (_, group) in graph.LAYERS.items() if group == 'receivers']
    assert receivers
    for pkg in receivers:
        assert 'vlc_stereo_camera' not in uses[pkg]['code'], pkg


def test_the_foundation_imports_no_project_package():
    assert graph.imports()['vlc_common'] == {'code': set(), 'test': set()}


def test_package_xml_declares_imports_tests_and_launched_packages():
    assert graph.undeclared() == []


def test_the_rules_catch_an_upward_import(tmp_path):
    """The checker itself: a foundation that imports a receiver is reported."""
    for pkg in ('vlc_common', 'train_localizer'):
        (tmp_path / pkg / pkg).mkdir(parents=True)
        (tmp_path / pkg / 'package.xml').write_text(
            f'<package><name>{pkg}</name></package>')
    (tmp_path / 'vlc_common' / 'vlc_common' / 'bad.py').write_text(
        'from train_localizer.core import fix\n')
    found = graph.violations(tmp_path)
    assert any('vlc_common (foundation) imports train_localizer' in f for f in found)
    assert any('cycle' not in f for f in found)
    assert graph.undeclared(tmp_path) == [
        'vlc_common/package.xml: its code imports train_localizer: add <exec_depend>']


def test_architecture_shows_the_current_package_graph():
    text = (ROOT / 'docs' / 'ARCHITECTURE.md').read_text(encoding='utf-8')
    assert graph.block() in text, ('run: python3 scripts/package_graph.py '
                                   '--write docs/ARCHITECTURE.md')
