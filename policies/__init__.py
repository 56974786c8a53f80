"""Phase labelling, FIRST sampling, ACT and flow-matching policies, training, rollout."""
