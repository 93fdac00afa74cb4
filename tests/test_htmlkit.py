"""The reports' inline figures (station.htmlkit.svg) are the same text for the same figure."""

import matplotlib.pyplot as plt
import numpy as np

from station.htmlkit import svg


def _figure():
    fig, ax = plt.subplots()
    x = np.linspace(0.0, 1.0, 50)
    ax.plot(x, x**2, label="a")
    ax.fill_between(x, 0.0, x)  # a clip path: its id was a random uuid's hash
    ax.legend()
    return fig


def test_the_same_figure_is_the_same_svg_without_a_date() -> None:
    first, second = svg(_figure()), svg(_figure())
    assert first.startswith("<svg")
    assert "clip-path" in first
    assert "<dc:date>" not in first
    assert first == second
