"""The admin page's figures: the dashboard, per-person statistics, time per action, reliability of confidences."""
