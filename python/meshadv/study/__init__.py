"""The human perceptual study, as a kit: pick the images, write a static 2AFC web page, analyse the answers.

MeshAdv's user study (Xiao et al., CVPR 2019) showed each adversarial render for 2 s, then asked which of two classes
(the true one and the attack's target, in random order) it was; each image got 5 answers, at most 50 per participant.

- :mod:`meshadv.study.selection`: the images (successful attacks, benign controls, attention checks);
- :mod:`meshadv.study.plan`: the balanced, seeded assignment of images to participants;
- :mod:`meshadv.study.export`: the static folder (HTML, JavaScript, CSS, images, plan);
- :mod:`meshadv.study.analysis`: the answers' summary, figure and attention-check filtering;
- :mod:`meshadv.study.proxies`: SSIM and PSNR of benign vs. adversarial renders (automatic stand-ins for people).
"""
