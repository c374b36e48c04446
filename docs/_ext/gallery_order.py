"""The gallery's order: the SPD scenes first, the newsletter's questions next, the tools last
(sphinx-gallery's `within_subsection_order`, named by its import path so the settings pickle)."""

ORDER = ["plot_spd_scenes.py", "plot_work_images.py", "plot_structure_drawn.py", "plot_stadium_sweep.py",
         "plot_compare.py", "plot_annealing.py", "plot_eye_light_puzzle.py", "plot_business_card.py",
         "plot_csg.py", "plot_animation.py", "plot_model_file.py", "plot_ray_casting.py"]


class GalleryOrder:
    def __init__(self, src_dir):
        self.src_dir = src_dir

    def __call__(self, filename: str):
        return (ORDER.index(filename) if filename in ORDER else len(ORDER), filename)

    def __repr__(self) -> str:
        return "GalleryOrder"
