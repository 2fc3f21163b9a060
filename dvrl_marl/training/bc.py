"""DDPG + HER + behaviour cloning (Nair et al., arXiv 1709.10089), as a small extension of SB3's DDPG.

The actor loss becomes ``policy_loss_weight * (-Q(s, pi(s)) + action_l2 * mean(pi(s)^2)) + bc_weight *
sum_i ||pi(s_i^d) - a_i^d||^2`` over a batch of demonstration pairs, where the Q-filter (optional) keeps only the
pairs whose demonstrated action the critic still rates above the policy's. Demonstrations also seed the replay
buffer (see ``runner``). The defaults follow the settings reported for the paper's OpenAI-Baselines run
(``psm_facts.md``): BC weight 0.0078 (summed over a 128-pair demo batch), action_l2 1.0, Q-filter off; the
policy-loss weight 0.001 is the demonstration code's ``prm_loss_weight`` (Nair et al.'s lambda_1), which keeps the
Q term from drowning the cloning term.
"""

from __future__ import annotations

import numpy as np
import torch as th
from stable_baselines3 import DDPG
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

__all__ = ["DDPGBC", "bc_loss", "q_filter_mask"]


def q_filter_mask(q_demo: th.Tensor, q_policy: th.Tensor) -> th.Tensor:
    """1 where the demonstrated action's value exceeds the policy action's (Nair et al.'s Q-filter), else 0."""
    return (q_demo > q_policy).float().reshape(-1)


def bc_loss(policy_actions: th.Tensor, demo_actions: th.Tensor, mask: th.Tensor | None = None) -> th.Tensor:
    """sum_i mask_i * ||pi(s_i) - a_i||^2 over the demo batch."""
    squared = ((policy_actions - demo_actions) ** 2).sum(dim=-1)
    if mask is not None:
        squared = squared * mask
    return squared.sum()


class DDPGBC(DDPG):
    """DDPG with an auxiliary behaviour-cloning loss on demonstrations.

    Args (besides DDPG's):
        bc_weight: weight of the summed BC loss (Baselines' ``aux_loss_weight``).
        demo_batch_size: demonstration pairs per gradient step.
        q_filter: apply Nair et al.'s Q-filter.
        action_l2: penalty on the actor's squared actions (Baselines' ``action_l2``).
        policy_loss_weight: weight of the Q and action_l2 terms (``prm_loss_weight``).
        clip_target: clip critic targets to [-1 / (1 - gamma), 0], the range of the sparse return (Baselines'
            ``clip_return``); it keeps the critic from diverging.
        random_action_probability: after ``learning_starts``, the chance that an exploration step takes a uniform
            random action instead of the noisy policy's (Baselines' ``random_eps``).

    With ``bc_weight=0`` and ``policy_loss_weight=1`` this is the paper's plain DDPG (Baselines' HER-DDPG: action
    penalty, clipped targets, random exploration steps), which SB3's ``DDPG`` lacks.
    """

    def __init__(self, *args, bc_weight: float = 0.0078, demo_batch_size: int = 128, q_filter: bool = False,
                 action_l2: float = 1.0, policy_loss_weight: float = 0.001, clip_target: bool = True,
                 random_action_probability: float = 0.0, **kwargs):
        if not 0.0 <= random_action_probability <= 1.0:
            raise ValueError(f"random_action_probability must lie in [0, 1], got {random_action_probability}")
        self.random_action_probability = float(random_action_probability)
        self.clip_target = bool(clip_target)
        self.bc_weight = float(bc_weight)
        self.policy_loss_weight = float(policy_loss_weight)
        self.demo_batch_size = int(demo_batch_size)
        self.q_filter = bool(q_filter)
        self.action_l2 = float(action_l2)
        self._demo_observations = None
        self._demo_actions = None
        super().__init__(*args, **kwargs)

    def set_demonstrations(self, observations: dict, actions: np.ndarray) -> None:
        """Demonstration pairs: a dict of (M, d) observation arrays and (M, act_dim) actions in [-1, 1]."""
        self._demo_observations = {k: th.as_tensor(np.asarray(v), dtype=th.float32, device=self.device)
                                    for k, v in observations.items()}
        self._demo_actions = th.as_tensor(np.asarray(actions), dtype=th.float32, device=self.device)

    def _demo_batch(self):
        count = len(self._demo_actions)
        index = th.as_tensor(np.random.randint(0, count, size=min(self.demo_batch_size, count)), device=self.device)
        return {k: v[index] for k, v in self._demo_observations.items()}, self._demo_actions[index]

    def _excluded_save_params(self) -> list[str]:
        return super()._excluded_save_params() + ["_demo_observations", "_demo_actions"]

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        action, buffer_action = super()._sample_action(learning_starts, action_noise, n_envs)
        if self.random_action_probability > 0 and self.num_timesteps >= learning_starts:
            # Seeded by SB3 through the action space, so runs stay reproducible.
            replace = np.array([self.action_space.np_random.random() < self.random_action_probability
                                for _ in range(n_envs)])
            if replace.any():
                random_actions = np.array([self.action_space.sample() for _ in range(n_envs)])
                action = np.where(replace[:, None], random_actions, action)
                buffer_action = np.where(replace[:, None], self.policy.scale_action(random_actions), buffer_action)
        return action, buffer_action

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        actor_losses, critic_losses, bc_losses = [], [], []
        for _ in range(gradient_steps):
            self._n_updates += 1
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            with th.no_grad():
                next_actions = self.actor_target(batch.next_observations)  # DDPG: no target smoothing
                next_q = th.min(th.cat(self.critic_target(batch.next_observations, next_actions), dim=1), dim=1,
                                keepdim=True)[0]
                target = batch.rewards + (1 - batch.dones) * self.gamma * next_q
                if self.clip_target:
                    target = target.clamp(-1.0 / (1.0 - self.gamma), 0.0)
            critic_loss = sum(F.mse_loss(q, target) for q in self.critic(batch.observations, batch.actions))
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()
            critic_losses.append(critic_loss.item())

            if self._n_updates % self.policy_delay == 0:
                policy_actions = self.actor(batch.observations)
                actor_loss = -self.critic.q1_forward(batch.observations, policy_actions).mean()
                actor_loss = self.policy_loss_weight * (actor_loss + self.action_l2 * (policy_actions**2).mean())
                if self._demo_actions is not None and self.bc_weight > 0:
                    demo_obs, demo_actions = self._demo_batch()
                    demo_policy_actions = self.actor(demo_obs)
                    mask = None
                    if self.q_filter:
                        with th.no_grad():
                            mask = q_filter_mask(self.critic.q1_forward(demo_obs, demo_actions),
                                                 self.critic.q1_forward(demo_obs, demo_policy_actions))
                    loss = bc_loss(demo_policy_actions, demo_actions, mask)
                    bc_losses.append(loss.item())
                    actor_loss = actor_loss + self.bc_weight * loss
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
                self.actor.optimizer.step()
                actor_losses.append(actor_loss.item())
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.actor.parameters(), self.actor_target.parameters(), self.tau)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        if actor_losses:
            self.logger.record("train/actor_loss", float(np.mean(actor_losses)))
        self.logger.record("train/critic_loss", float(np.mean(critic_losses)))
        if bc_losses:
            self.logger.record("train/bc_loss", float(np.mean(bc_losses)))
