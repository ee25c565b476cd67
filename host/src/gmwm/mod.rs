//! Generalized method of wavelet moments (GMWM): latent error-process models with their
//! closed-form Haar wavelet variance, the weighted least-squares fit of a model to a wavelet
//! variance, parameter intervals, goodness of fit, model selection, and the static-versus-
//! dynamic comparison of the seed paper's Table I (Stebler et al. 2015, eqs. 15-19).

pub mod compare;
pub mod covariance;
pub mod fit;
pub mod inference;
pub mod model;
