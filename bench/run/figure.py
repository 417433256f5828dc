"""Figures; plotting only reads records (or series handed over by the run loop)."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def plot_run(series, path, title=""):
    """Three panels against step: time per step, contacts, kinetic energy."""
    fig, ax = plt.subplots(3, 1, figsize=(6.4, 7.2), sharex=True)
    ax[0].plot(series["step"], [1e3 * t for t in series["totalT"]], lw=0.8)
    ax[0].set_ylabel("totalT [ms/step]")
    ax[1].plot(series["step"], series["n_contacts"], lw=0.8, color="C1")
    ax[1].set_ylabel("contacts")
    ax[2].semilogy(series["step"], [max(e, 1e-300) for e in series["ke"]], lw=0.8, color="C2")
    ax[2].set_ylabel("kinetic energy [J]")
    ax[2].set_xlabel("step")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
