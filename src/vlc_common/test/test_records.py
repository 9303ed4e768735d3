"""The record layouts document every field they define."""
from vlc_common.core import records


def test_the_field_tables_in_the_docstring_list_every_field():
    for name in records.PAIR_DTYPE.names:
        assert f'``{name}``' in records.__doc__, name
    for name in records.LAMP_DTYPE.names:
        assert f'``{name}``' in records.__doc__, name
