"""``detector_train --ema``: integer buffers (the CenterNet graph's int32 shape constants) are
copied, not averaged; averaged, 3 became 2 and the saved checkpoint failed to run."""

import torch
from detector_node.train import _ema_of_floats
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn


class _Net(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.weight = torch.nn.Parameter(torch.ones(4))
        self.register_buffer("axis", torch.tensor([3, 7], dtype=torch.int32))


def _run(avg_fn) -> AveragedModel:
    net = _Net()
    ema = AveragedModel(net, multi_avg_fn=avg_fn, use_buffers=True)
    for _ in range(5):
        with torch.no_grad():
            net.weight.add_(1.0)
        ema.update_parameters(net)
    return ema


def test_ema_averages_floats_and_keeps_integer_buffers():
    ema = _run(_ema_of_floats(get_ema_multi_avg_fn(0.9)))
    assert ema.module.axis.tolist() == [3, 7]
    w = ema.module.weight.detach()
    assert torch.all(w > 1.0) and torch.all(w < 6.0)  # averaged, not copied (6)


def test_plain_ema_truncates_integer_buffers():
    """What the fix is for (torch's EMA over every buffer)."""
    ema = _run(get_ema_multi_avg_fn(0.9))
    assert ema.module.axis.tolist() != [3, 7]
