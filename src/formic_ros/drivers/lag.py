"""How stale a rollout may be, in one place for the trainer node, the learning host, the launcher
and the command line (none of which need torch to read it)."""

DEFAULT_MAX_LAG = 4  # weights versions a rollout may lag behind and still be learned from
AHEAD_CHUNKS = 2  # asynchronous hosts (switch "newest") send at most this many rollouts a weights version
