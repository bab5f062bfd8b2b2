"""What people look at: the paper's tables, figures, sample pictures, ``inspect`` and the HTML report."""
