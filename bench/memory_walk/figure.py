"""What the memory_walk plots share: one figure, saved the same way."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def new():
    """A figure and its axes, at the size every memory_walk plot uses."""
    return plt.subplots(figsize=(10, 4.5))


def save(fig, ax, path, xlabel, ylabel, title, grid_which="major"):
    """Labels, grid and legend, then writes `path` and says so."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which=grid_which, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    print(f"plot: {path}")
