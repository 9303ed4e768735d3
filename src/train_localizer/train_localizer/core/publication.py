"""When the localizer publishes a pose.

Poses are emitted on a grid of ``publish_rate_hz`` in sensor time as the IMU passes each
grid instant (so also between fixes, and with exact stamps), and, with
``publish_on_fix``, once more right after a fix at the newest step, so a frame's
information is published as soon as it is used. After a cold start the output is held
until the chainage 1σ is below ``max_sigma_m`` (a single-frame start does not know the
speed yet); from then on every pose is published, with its covariance and the integrity
state saying how good it is. A configured prior is published at once, whatever its σ.
"""
from vlc_common.core.observation import NS_PER_S


class PoseGate:
    """The publish grid and the post-fix pose.

    Parameters
    ----------
    publish_rate_hz : float
        Pose grid in sensor time, Hz.
    max_sigma_m : float
        Chainage 1σ below which a cold start's output opens, m.
    """

    def __init__(self, publish_rate_hz, max_sigma_m):
        self.period_ns = int(round(NS_PER_S / publish_rate_hz))
        self.max_sigma_m = max_sigma_m
        self.reset()

    def reset(self):
        self.next_grid_ns = None     # next grid instant, ns
        self.last_pub_ns = None      # stamp of the last pose published, ns
        self.fix_pending = False     # a post-fix pose is due
        self.open = False            # the output has opened (σ small enough, or a prior)
        self.start_ns = None         # no pose before this stamp (the initialisation)

    def start_grid(self, t_ns):
        """Start the grid after the first step ``t_ns`` (once)."""
        if self.next_grid_ns is None:
            self.next_grid_ns = (t_ns // self.period_ns + 1) * self.period_ns

    def skip_to(self, t_ns):
        """No grid pose before ``t_ns``."""
        if self.next_grid_ns is not None and self.next_grid_ns < t_ns:
            self.next_grid_ns = -(-t_ns // self.period_ns) * self.period_ns

    def open_at(self, t_ns):
        """Publish from ``t_ns`` on, at once (a configured prior)."""
        self.start_ns = t_ns
        self.open = True

    def _after_last(self, t_ns):
        return self.last_pub_ns is None or t_ns > self.last_pub_ns

    def _may_publish(self, t_ns, sigma2_at):
        if not self.open:
            self.open = sigma2_at(t_ns) <= self.max_sigma_m ** 2
        return self.open

    def due(self, newest_ns, initialized, sigma2_at):
        """[(stamp_ns, kind)] of the poses to publish now that the history reaches
        ``newest_ns`` (none before the filter is ``initialized``; the grid advances all
        the same); ``sigma2_at(t)`` is the published chainage variance at ``t``, m².
        """
        out = []
        if self.next_grid_ns is not None and newest_ns - self.next_grid_ns > NS_PER_S:
            # A jump forward: do not flood the output with a second of grid poses.
            self.next_grid_ns = (newest_ns // self.period_ns) * self.period_ns
        while self.next_grid_ns is not None and self.next_grid_ns <= newest_ns:
            g = self.next_grid_ns
            self.next_grid_ns += self.period_ns
            if (initialized and g >= self.start_ns and self._after_last(g)
                    and self._may_publish(g, sigma2_at)):
                out.append((g, 'grid'))
                self.last_pub_ns = g
        if (self.fix_pending and initialized and self._after_last(newest_ns)
                and self._may_publish(newest_ns, sigma2_at)):
            out.append((newest_ns, 'fix'))
            self.last_pub_ns = newest_ns
            self.fix_pending = False
        return out
