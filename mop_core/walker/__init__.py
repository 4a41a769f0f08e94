"""The walker: its tasks (one body, several reward functions), batched MuJoCo environments, rollouts."""
