import torch

from gpja.render import sample_texture


def test_texel_centres_and_orientation():
    tex = torch.arange(12, dtype=torch.float64).reshape(3, 4, 1)  # row 0 is the top of the image
    # OBJ convention: v = 1 is the top row; texel centres at ((j + .5)/4, 1 - (i + .5)/3)
    uv = torch.tensor([[0.5 / 4, 1 - 0.5 / 3], [3.5 / 4, 0.5 / 3]], dtype=torch.float64)
    torch.testing.assert_close(sample_texture(tex, uv)[:, 0], torch.tensor([0.0, 11.0], dtype=torch.float64))


def test_bilinear_midpoint():
    tex = torch.tensor([[[0.0], [2.0]], [[4.0], [6.0]]], dtype=torch.float64)
    torch.testing.assert_close(sample_texture(tex, torch.tensor([[0.5, 0.5]], dtype=torch.float64)),
                               torch.tensor([[3.0]], dtype=torch.float64))


def test_gradcheck_texture_and_uv():
    torch.manual_seed(2)
    tex = torch.rand(5, 6, 3, dtype=torch.float64, requires_grad=True)
    uv = (torch.rand(8, 2, dtype=torch.float64) * 0.8 + 0.1).requires_grad_(True)
    assert torch.autograd.gradcheck(sample_texture, (tex, uv))
