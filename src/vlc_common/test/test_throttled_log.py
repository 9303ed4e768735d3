from vlc_common.throttled_log import ThrottledWarnings


class _Logger:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(text)


def test_one_warning_per_kind_and_period_with_the_suppressed_count():
    now = [0.0]
    log = _Logger()
    w = ThrottledWarnings(log, 1.0, clock=lambda: now[0])
    formatted = []

    def text():
        formatted.append(1)
        return 'gap'

    assert w.warn('gap', text)
    for _ in range(5):
        now[0] += 0.1
        assert not w.warn('gap', text)
    assert w.suppressed('gap') == 5
    assert w.warn('reset', 'reset')                  # another kind is not hidden
    now[0] += 0.6
    assert w.warn('gap', text)
    assert log.lines == ['gap', 'reset', 'gap (+5 more since the last one)']
    assert len(formatted) == 2                       # suppressed messages are not formatted
    assert w.suppressed('gap') == 0
