"""How stale a rollout the trainer node still learns from, in one place for the trainer node, the
launcher and the command line (none of which need torch to read it)."""

DEFAULT_MAX_LAG = 4  # weights versions a rollout may lag behind and still be learned from
