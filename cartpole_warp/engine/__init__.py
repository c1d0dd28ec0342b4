"""The engine: the stage (``scene``), the batched env (``env``) and its Warp kernels (``kernels``), the camera
(``camera``), domain randomization (``randomization``), devices, shards and graphs (``runtime``), torch and Warp on one
CUDA stream (``streams``). It knows no task."""
