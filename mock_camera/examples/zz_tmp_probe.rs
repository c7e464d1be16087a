use mock_camera::*;
fn std_at(r:&Renderer,img:&image::RgbImage,x:f64,y:f64)->f64{let inv=r.homography.inverse().unwrap();let (u,v)=inv.apply(x,y).unwrap();let (u,v)=(u.round() as i64,v.round() as i64);let mut a=vec![];for dv in -7..=7{for du in -7..=7{a.push(img.get_pixel((u+du) as u32,(v+dv) as u32)[0] as f64)}}let m=a.iter().sum::<f64>()/a.len() as f64;(a.iter().map(|x|(x-m)*(x-m)).sum::<f64>()/a.len() as f64).sqrt()}
fn main(){let (w,h)=(1200,800);let r=Renderer::new(w,h,Homography::oblique_view(w,h));println!("{:?}",r.homography.m);
let parts=vec![Shape::Circle{cx:0.0,cy:0.0,r:20.0}];
for l in [Illumination::Front,Illumination::Side,Illumination::Top,Illumination::Dark]{for sc in [false,true]{let img=r.render(&Scene{layer:1,fused:&parts,scanned:sc,illumination:l});println!("{l:?} scanned={sc}: metal-spot std {:.1}, powder std {:.1}",std_at(&r,&img,0.0,0.0),std_at(&r,&img,60.0,-60.0));}}
let p=demo_parts(500);let img=r.render(&Scene{layer:500,fused:&p,scanned:true,illumination:Illumination::Top});img.save("/tmp/mc/post_top.png").unwrap();}
