"""What a finished run tells its user."""

from __future__ import annotations


def print_summary(summary: dict) -> None:
    rmse, nn = summary["val_rmse_unobserved"], summary["nearest_fill_rmse_unobserved"]
    verdict = "better than" if rmse < nn else "not yet better than"
    print(
        "\n".join(
            [
                f"finished {summary['steps']} steps in {summary['wall_s'] / 60:.1f} min",
                (
                    f"  validation RMSE on unobserved cells: {rmse:.3f} m (best {summary['best_val_rmse_unobserved']:.3f} m)"
                    f" - {verdict} nearest-neighbour fill: {nn:.3f} m"
                ),
                f"  run folder:   {summary['run_dir']}",
                f"  tensorboard:  tensorboard --logdir {summary['tensorboard']}",
                f"  checkpoint:   {summary['checkpoint']} (best: {summary['best_checkpoint']})",
                f"  images:       {summary['images']}",
            ]
        )
    )
