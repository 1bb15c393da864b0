"""The worker side of handloop: the Celery app (`workers.tasks.app`), its thin tasks
(`workers.tasks.definitions`) and the job services they call, one module per kind of work:

- `fits`: fit samples from annotations or predictions and record the fits (workers.tasks.records);
- `training`: train HandSegNet and MVNet on a round's accepted samples, checkpoints per round;
- `inference`: predict masks and 3D keypoints for the samples not yet in the dataset;
- `rounds`: the bootstrap round, orchestrated as a Celery canvas of the above (docs/deployment.md).

Services take ids, re-load rows from the database and files from storage, and record results through
backend.services; they are testable without a broker. Task names and queues: backend.broker.celery_queue.
"""
