"""Batched forward kinematics of whole trajectories with pytorch-kinematics.

The chain is built from oscar's own parse of the URDF (:mod:`oscar_core.kinematics.urdf`)
with every static transform computed in float64, so FK accuracy is not
limited by float32 joint origins. Mimic joints are filled in from their
source joints before the chain is evaluated.
"""

from __future__ import annotations

import torch

from .urdf import KinematicTree

__all__ = ["ForwardKinematics", "build_chain_from_tree"]


def build_chain_from_tree(tree: KinematicTree, dtype=torch.float64, device="cpu"):
    """A ``pytorch_kinematics.Chain`` for ``tree`` with float64 static offsets."""
    import pytorch_kinematics as pk
    from pytorch_kinematics import frame as pkf, transforms as pkt

    children: dict[str, list] = {}
    for j in tree.joints:
        children.setdefault(j.parent, []).append(j)

    def make_frame(link: str, joint) -> pkf.Frame:
        f = pkf.Frame(link)
        if joint is None:
            f.joint = pkf.Joint(dtype=torch.float64)
        else:
            jtype = {"continuous": "revolute"}.get(joint.type, joint.type)
            offset = pkt.Transform3d(matrix=torch.tensor(joint.origin, dtype=torch.float64), dtype=torch.float64)
            f.joint = pkf.Joint(
                joint.name,
                offset=offset,
                joint_type=jtype,
                axis=tuple(joint.axis.tolist()),
                dtype=torch.float64,
                limits=(joint.lower, joint.upper) if joint.lower is not None else None,
            )
        f.link = pkf.Link(link)
        f.children = [make_frame(j.child, j) for j in children.get(link, [])]
        return f

    chain = pk.Chain(make_frame(tree.root, None), dtype=torch.float64)
    return chain.to(dtype=dtype, device=device)


class ForwardKinematics:
    """FK for a :class:`KinematicTree`: ``q (T, J)`` → link poses ``(T, K, 4, 4)``.

    J follows ``tree.joint_names`` (mimic joints excluded). Poses are in the
    robot's root-link frame, or in the world when ``base_pose`` is given.
    """

    def __init__(self, tree: KinematicTree, dtype=torch.float64, device="cpu"):
        self.tree = tree
        self.dtype = dtype
        self.device = torch.device(device)
        self.chain = build_chain_from_tree(tree, dtype=dtype, device=self.device)
        chain_names = self.chain.get_joint_parameter_names()
        index = {n: i for i, n in enumerate(tree.joint_names)}
        # chain parameter k = mult[k] * q[:, src[k]] + offset[k]
        src, mult, off = [], [], []
        for name in chain_names:
            j = tree.joint(name)
            if j.mimic is None:
                src.append(index[name])
                mult.append(1.0)
                off.append(0.0)
            else:
                src.append(index[j.mimic[0]])
                mult.append(j.mimic[1])
                off.append(j.mimic[2])
        self._src = torch.tensor(src, dtype=torch.long, device=self.device)
        self._mult = torch.tensor(mult, dtype=dtype, device=self.device)
        self._off = torch.tensor(off, dtype=dtype, device=self.device)
        self._is_identity_map = src == list(range(len(src))) and all(m == 1.0 for m in mult) and not any(off)
        self._frame_index = dict(self.chain.frame_to_idx)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.tree.joint_names

    def frame_indices(self, links) -> torch.Tensor:
        missing = [l for l in links if l not in self._frame_index]
        if missing:
            raise KeyError(f"{self.tree.source}: unknown links {missing}; links: {', '.join(self.tree.links)}")
        return torch.tensor([self._frame_index[l] for l in links], dtype=torch.long, device=self.device)

    def full_configuration(self, q: torch.Tensor) -> torch.Tensor:
        """(T, J) actuated joints → (T, J_chain) including mimic joints, chain order."""
        if self._is_identity_map:
            return q
        return q[:, self._src] * self._mult + self._off

    def __call__(self, q, links, base_pose=None) -> torch.Tensor:
        """Poses of ``links``.

        q: (T, J) radians / metres in ``joint_names`` order (numpy or torch).
        links: K link names, or a LongTensor from :meth:`frame_indices`.
        base_pose: optional (T, 4, 4) or (4, 4) pose of the root link in the world.
        returns: (T, K, 4, 4) tensor of ``self.dtype`` on ``self.device``.
        """
        q = torch.as_tensor(q, dtype=self.dtype, device=self.device)
        if q.ndim != 2 or q.shape[1] != len(self.joint_names):
            raise ValueError(f"q: expected shape (T, {len(self.joint_names)}), found {tuple(q.shape)}")
        idx = links if isinstance(links, torch.Tensor) else self.frame_indices(links)
        if q.shape[0] == 0:
            return torch.empty(0, len(idx), 4, 4, dtype=self.dtype, device=self.device)
        if self.chain.n_joints == 0:
            all_frames = self.chain._static_offsets.unsqueeze(1).expand(-1, q.shape[0], 4, 4)
        else:
            all_frames = self.chain.forward_kinematics_tensor(self.full_configuration(q))  # (F, T, 4, 4)
        poses = all_frames[idx].transpose(0, 1)  # (T, K, 4, 4)
        if base_pose is not None:
            base = torch.as_tensor(base_pose, dtype=self.dtype, device=self.device)
            if base.shape not in ((4, 4), (q.shape[0], 4, 4)):
                raise ValueError(f"base_pose: expected shape (4, 4) or ({q.shape[0]}, 4, 4), found {tuple(base.shape)}")
            poses = (base.unsqueeze(-3) if base.ndim == 3 else base) @ poses
        return poses
