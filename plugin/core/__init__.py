"""What every stage uses: progress and cancellation, exact coordinate transforms, paths."""
