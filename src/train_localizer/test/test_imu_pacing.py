"""ImuPacer: IMU samples reach the filter no further ahead of the frames than lead_s."""
import pytest

from train_localizer.core.imu_pacing import ImuPacer, ImuPacingConfig

MS = 1_000_000
IMU_NS = 2_500_000            # 400 Hz


def _burst(pacer, t0_ns, t1_ns):
    for t in range(t0_ns, t1_ns, IMU_NS):
        pacer.push(t, t)


def test_before_any_frame_every_sample_goes_on():
    pacer = ImuPacer()
    _burst(pacer, 0, 2000 * MS)
    assert len(pacer.release(now_s=0.0)) == 800 and len(pacer) == 0


def test_a_catch_up_burst_is_released_as_the_frames_come():
    """A stalled IMU catches up with 1.5 s at once: only lead_s past the newest frame
    goes on; each later frame releases more, in order, none lost.
    """
    pacer = ImuPacer(ImuPacingConfig(lead_s=0.5, silence_s=0.5))
    pacer.on_frame(6000 * MS, now_s=10.0)
    _burst(pacer, 6000 * MS, 7500 * MS)
    out = pacer.release(now_s=10.01)
    assert out and max(out) <= 6500 * MS and len(pacer) == 600 - len(out)
    seen = list(out)
    for k in range(1, 46):                                 # the queued frames, 33 ms apart
        pacer.on_frame(6000 * MS + k * 33 * MS, now_s=10.01 + k * 0.001)
        seen += pacer.release(now_s=10.01 + k * 0.001)
    assert seen == list(range(6000 * MS, 7500 * MS, IMU_NS))


def test_silent_frames_release_everything_after_silence_s():
    """A camera dropout: the filter must coast on the IMU."""
    pacer = ImuPacer(ImuPacingConfig(lead_s=0.5, silence_s=0.5))
    pacer.on_frame(0, now_s=0.0)
    _burst(pacer, 0, 3000 * MS)
    assert len(pacer.release(now_s=0.4)) == 201             # up to 0.5 s inclusive
    assert len(pacer.release(now_s=0.6)) == 1200 - 201


def test_the_backlog_is_bounded():
    """An IMU clock far ahead of the camera's: beyond max_backlog the oldest go on."""
    pacer = ImuPacer(ImuPacingConfig(lead_s=0.5, silence_s=0.5, max_backlog=100))
    pacer.on_frame(0, now_s=0.0)
    _burst(pacer, 10_000 * MS, 11_000 * MS)                # 10 s ahead of the frames
    out = pacer.release(now_s=0.01)
    assert out == list(range(10_000 * MS, 10_000 * MS + 300 * IMU_NS, IMU_NS))
    assert len(pacer) == 100 and pacer.held_max == 400


def test_a_frame_stream_that_steps_back_holds_the_samples_of_the_old_base_until_silence():
    pacer = ImuPacer(ImuPacingConfig(lead_s=0.5, silence_s=0.5))
    pacer.on_frame(5000 * MS, now_s=1.0)
    pacer.on_frame(1000 * MS, now_s=1.1)                   # new time base, 4 s back
    _burst(pacer, 5000 * MS, 5100 * MS)
    assert pacer.release(now_s=1.2) == []
    assert len(pacer.release(now_s=1.7)) == 40


@pytest.mark.parametrize('field', ['lead_s', 'silence_s'])
def test_config_rejects_non_positive_times(field):
    with pytest.raises(ValueError):
        ImuPacingConfig(**{field: 0.0})


def test_time_spent_on_released_samples_is_not_silence():
    pacer = ImuPacer(ImuPacingConfig(lead_s=0.5, silence_s=0.5))
    pacer.on_frame(0, now_s=0.0)
    _burst(pacer, 0, 3000 * MS)
    assert len(pacer.release(now_s=0.1)) == 201
    pacer.credit(0.8)                          # the node was busy handing them on
    assert pacer.release(now_s=0.9) == []
    assert len(pacer.release(now_s=1.5)) == 1200 - 201
