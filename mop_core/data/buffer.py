"""In-memory transitions as torch tensors: the replay buffer and uniform minibatch sampling."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch


@dataclass
class Batch:
    """A minibatch of transitions (float32 tensors; ``terminals`` as 0/1 floats)."""

    observations: torch.Tensor  # [B, obs]
    actions: torch.Tensor  # [B, act]
    rewards: torch.Tensor  # [B]
    next_observations: torch.Tensor  # [B, obs]
    terminals: torch.Tensor  # [B]

    def to(self, device: torch.device) -> "Batch":
        return Batch(*(t.to(device, non_blocking=True) for t in self.as_dict().values()))

    def as_dict(self) -> dict[str, torch.Tensor]:
        """The fields by name (a captured step's inputs, mop_core.learning.graphs)."""
        return {field.name: getattr(self, field.name) for field in fields(self)}

    @classmethod
    def from_dict(cls, tensors: dict[str, torch.Tensor]) -> "Batch":
        """The batch of :meth:`as_dict`'s fields in ``tensors`` (other keys ignored: a captured step's buffers)."""
        return cls(*(tensors[field.name] for field in fields(cls)))


@dataclass
class TransitionTensors:
    """A whole dataset held in memory on one device; :meth:`sample` draws uniform minibatches."""

    observations: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    next_observations: torch.Tensor
    terminals: torch.Tensor
    timeouts: torch.Tensor

    def __len__(self) -> int:
        return self.observations.shape[0]

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], rewards: np.ndarray | None = None,
                    device: torch.device | str = "cpu") -> "TransitionTensors":
        """From dataset arrays (D4RL keys); ``rewards`` replaces the stored rewards (relabelling)."""
        def f32(x: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=np.float32), device=device)
        return cls(
            observations=f32(arrays["observations"]),
            actions=f32(arrays["actions"]),
            rewards=f32(arrays["rewards"] if rewards is None else rewards),
            next_observations=f32(arrays["next_observations"]),
            terminals=f32(arrays["terminals"]),
            timeouts=torch.as_tensor(np.asarray(arrays["timeouts"], dtype=bool), device=device),
        )

    def sample(self, batch_size: int, generator: torch.Generator) -> Batch:
        index = torch.randint(len(self), (batch_size,), generator=generator, device=generator.device)
        index = index.to(self.observations.device)
        return Batch(self.observations[index], self.actions[index], self.rewards[index],
                     self.next_observations[index], self.terminals[index])


class ReplayBuffer:
    """Fixed-capacity store of every transition an online learner sees, in insertion order.

    Besides what TD3 samples it keeps the physics state and reward features of each next state
    (float64), so its prefix is the *medium-replay* dataset without any re-simulation.
    """

    def __init__(self, capacity: int, obs_dim: int, act_dim: int, physics_dim: int, feature_dim: int):
        self.capacity = capacity
        self.size = 0
        self.observations = torch.zeros(capacity, obs_dim)
        self.actions = torch.zeros(capacity, act_dim)
        self.rewards = torch.zeros(capacity)
        self.next_observations = torch.zeros(capacity, obs_dim)
        self.terminals = torch.zeros(capacity)
        self.timeouts = np.zeros(capacity, dtype=bool)
        self.next_physics = np.zeros((capacity, physics_dim))
        self.features = np.zeros((capacity, feature_dim))

    def add(self, obs, action, reward, next_obs, terminal, timeout, next_physics, features) -> None:
        if self.size >= self.capacity:
            raise RuntimeError(f"replay buffer full ({self.capacity} transitions)")
        i = self.size
        self.observations[i] = torch.as_tensor(obs)
        self.actions[i] = torch.as_tensor(action)
        self.rewards[i] = float(reward)
        self.next_observations[i] = torch.as_tensor(next_obs)
        self.terminals[i] = float(terminal)
        self.timeouts[i] = timeout
        self.next_physics[i] = next_physics
        self.features[i] = features
        self.size += 1

    FIELDS = ("observations", "actions", "rewards", "next_observations", "terminals", "timeouts", "next_physics",
              "features")

    def state_dict(self) -> dict:
        """The filled part of every field (copies), for a resume file."""
        return {"size": self.size} | {name: getattr(self, name)[:self.size].copy() if isinstance(
            getattr(self, name), np.ndarray) else getattr(self, name)[:self.size].clone() for name in self.FIELDS}

    def load_state_dict(self, state: dict) -> None:
        if state["size"] > self.capacity:
            raise ValueError(f"state: {state['size']} transitions do not fit a buffer of {self.capacity}")
        self.size = state["size"]
        for name in self.FIELDS:
            getattr(self, name)[:self.size] = state[name]

    def sample(self, batch_size: int, generator: torch.Generator) -> Batch:
        """A uniform minibatch on the CPU (``generator`` must be a CPU generator)."""
        index = torch.randint(self.size, (batch_size,), generator=generator)
        return Batch(self.observations[index], self.actions[index], self.rewards[index],
                     self.next_observations[index], self.terminals[index])

    def arrays(self, end: int | None = None) -> dict[str, np.ndarray]:
        """The first ``end`` transitions as dataset arrays (D4RL keys plus physics and features)."""
        n = self.size if end is None else end
        return {
            "observations": self.observations[:n].numpy().copy(),
            "actions": self.actions[:n].numpy().copy(),
            "rewards": self.rewards[:n].numpy().copy(),
            "next_observations": self.next_observations[:n].numpy().copy(),
            "terminals": self.terminals[:n].numpy().astype(bool),
            "timeouts": self.timeouts[:n].copy(),
            "next_physics": self.next_physics[:n].copy(),
            "reward_features": self.features[:n].copy(),
        }
